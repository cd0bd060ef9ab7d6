"""Region levels from nested place assignments, and the paper's place-to-place weight.

Weight (paper, after ATLAS Navigator): w_ij = |p_i - p_j| + gamma * (1 - cos(e_i, e_j)), metres
plus gamma times a cosine distance. Level 1 groups places, level k groups the regions of level
k - 1; a region's position is the centroid of its children and its embedding the normalised mean
of theirs.
"""

from __future__ import annotations

import numpy as np

from terra.graph.scene_graph import RegionLevel
from terra.perception.text import normalize_rows


def paper_weight(p_i: np.ndarray, p_j: np.ndarray, e_i: np.ndarray, e_j: np.ndarray, gamma: float) -> np.ndarray:
    """Row-wise w = |p_i - p_j| + gamma (1 - cos(e_i, e_j)) for (n, 3) positions (metres) and
    (n, D) embeddings (any norm; zero rows count as cos = 0)."""
    cos = np.einsum("ij,ij->i", normalize_rows(e_i), normalize_rows(e_j))
    return np.linalg.norm(np.asarray(p_i, float) - np.asarray(p_j, float), axis=1) + gamma * (
        1.0 - np.clip(cos, -1.0, 1.0)
    )


def canonical_labels(labels: np.ndarray) -> np.ndarray:
    """Relabel 0..R-1 in order of each label's first occurrence (deterministic, dense)."""
    labels = np.asarray(labels)
    _, first, inverse = np.unique(labels, return_index=True, return_inverse=True)
    rank = np.empty(len(first), dtype=np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(len(first))
    return rank[inverse.ravel()]


def build_levels(assignments: list[np.ndarray], position: np.ndarray, embedding: np.ndarray) -> list[RegionLevel]:
    """Region levels from per-level place assignments (each (P,), coarser with each level).

    Every level is made a proper coarsening of the one below: a level-k region's parent is the
    level-(k+1) label of its first place, so every node has exactly one parent even if the input
    were not perfectly nested.
    """
    position = np.asarray(position, dtype=np.float64)
    embedding = np.asarray(embedding, dtype=np.float32)
    levels: list[RegionLevel] = []
    child_pos, child_emb = position, embedding
    child_of_place = np.arange(len(position))  # place -> node of the level below
    for k, labels in enumerate(assignments, start=1):
        labels = np.asarray(labels)
        # Parent of each child = the label of the child's first place.
        first_place = np.full(len(child_pos), len(position))
        np.minimum.at(first_place, child_of_place, np.arange(len(position)))
        parent = canonical_labels(labels[first_place])
        R = int(parent.max()) + 1 if len(parent) else 0
        count = np.bincount(parent, minlength=R).astype(np.float64)
        pos = (
            np.stack([np.bincount(parent, weights=child_pos[:, d], minlength=R) for d in range(3)], axis=1)
            / count[:, None]
        )
        emb = np.zeros((R, child_emb.shape[1]), np.float32)
        np.add.at(emb, parent, child_emb)
        levels.append(
            RegionLevel(level=k, position=pos, embedding=normalize_rows(emb), parent_of_child=parent.astype(np.int64))
        )
        child_pos, child_emb = pos, levels[-1].embedding
        child_of_place = parent[child_of_place]
    return levels
