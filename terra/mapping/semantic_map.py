"""The metric-semantic map: sparse global points with terrain votes and embedding-bank counts.

All positions are in the map frame, metres. Embeddings are float32 unit vectors of the map's
embedder (`embedder`, dimension D). Per-point semantics are sparse (DESIGN.md decision 2): a query
never builds an N x D array.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from terra.mapping.visibility import VisibilityIndex


@dataclass
class ImageTable:
    """Per image: stamp (s), camera index, camera pose T_map_cam (4x4), whole-image embedding (D,)."""

    stamp: np.ndarray  # (M,) float64 seconds
    camera: np.ndarray  # (M,) int16 camera index
    T_map_cam: np.ndarray  # (M, 4, 4) float64
    embedding: np.ndarray  # (M, D) float32 unit
    camera_names: list[str] = field(default_factory=list)

    def __len__(self) -> int:
        return int(self.stamp.shape[0])

    @property
    def position(self) -> np.ndarray:
        """(M, 3) camera centres in the map frame, metres."""
        return self.T_map_cam[:, :3, 3]


@dataclass(frozen=True)
class FusionRows:
    """Which fusion made a map and each map point's row in it: `fusion` an id the fusion took when
    it started, `rows` (N,) int64 the creation-order row of each point (a permutation of 0..N-1).
    Rows are only ever appended, so two maps of one fusion pair their points by row, without a
    search (terra.graph.update compares a live map's versions this way).

    From the fusion's `finish`, also: `index` (N,) int64 the map point of each row (the inverse of
    `rows`), `serial` which of the fusion's maps this is (1, 2, ...), and `changed` the sorted rows
    whose position or votes changed since its map `serial - 1` (new rows included), so a consumer
    that read that map recomputes only those rows."""

    fusion: str
    rows: np.ndarray
    index: np.ndarray | None = None
    serial: int = 0
    changed: np.ndarray | None = None


@dataclass
class MetricSemanticMap:
    """points: (N, 3) float32. terrain_votes: (N, T) uint16 votes per terrain class.
    counts: (N, K) CSR int32 observations of bank entries (one image adds at most one per pair).
    bank: (K, D) float32 unit embeddings. terrain_embeddings: (T, D) text embeddings of the terrain
    class names. images: the image table (may be empty for LiDAR-only sources).
    visibility: which images saw which part of the map (None = unknown, e.g. LiDAR-only).
    fusion_rows: the points' rows in the fusion that made the map (None for a map read from a file).
    """

    points: np.ndarray
    terrain_classes: list[str]
    terrain_votes: np.ndarray
    terrain_embeddings: np.ndarray
    counts: sp.csr_matrix
    bank: np.ndarray
    images: ImageTable
    embedder: str
    voxel_size: float = 0.4
    visibility: VisibilityIndex | None = None
    fusion_rows: FusionRows | None = field(default=None, repr=False)
    _avg_norm: np.ndarray | None = field(default=None, repr=False)
    _max_id: np.ndarray | None = field(default=None, repr=False)

    def __len__(self) -> int:
        return int(self.points.shape[0])

    @property
    def dim(self) -> int:
        return int(self.bank.shape[1]) if self.bank.ndim == 2 else int(self.terrain_embeddings.shape[1])

    def ms_avg_norms(self) -> np.ndarray:
        """(N,) row norms of counts @ bank (0 = no observation), cached; stored in the bundle at
        map time so a query process does not recompute them (see ms_avg_norms below)."""
        if self._avg_norm is None:
            self._avg_norm = ms_avg_norms(self.counts, self.bank)
        return self._avg_norm

    def ms_max_ids(self) -> np.ndarray:
        """(N,) bank id with the most observations per point (ties: lowest id); -1 = unobserved."""
        if self._max_id is None:
            self._max_id = ms_max_ids(self.counts)
        return self._max_id

    def ms_avg_similarity(self, queries: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        """(n, Q) cosine of each point's MS-Avg feature (count-weighted mean of bank vectors) with
        unit query vectors (Q, D); 0 for unobserved points. `rows` restricts to a subset of points."""
        s = self.bank @ np.asarray(queries, dtype=np.float32).T  # (K, Q)
        counts = self.counts if rows is None else self.counts[rows]
        norms = self.ms_avg_norms() if rows is None else self.ms_avg_norms()[rows]
        num = np.asarray(counts @ s, dtype=np.float32)
        return np.divide(num, norms[:, None], out=np.zeros_like(num), where=norms[:, None] > 0)

    def ms_max_similarity(self, queries: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
        """(n, Q) cosine of each point's MS-Max feature (its most observed bank vector) with the
        queries; 0 for unobserved points."""
        s = self.bank @ np.asarray(queries, dtype=np.float32).T
        ids = self.ms_max_ids() if rows is None else self.ms_max_ids()[rows]
        out = np.zeros((ids.shape[0], s.shape[1]), dtype=np.float32)
        seen = ids >= 0
        out[seen] = s[ids[seen]]
        return out

    def images_observing(self, positions: np.ndarray, max_range: float = 20.0) -> tuple[list[np.ndarray], np.ndarray]:
        """Per position (P, 3, metres, map frame): indices of the images whose camera centre was
        within `max_range` metres of it and whose view contained it (not occluded), and (P,) the
        index of the nearest image that saw it at any range (-1 if none). Resolution: the map's
        visibility cells (`visibility.cell_size` metres, neighbouring cells included)."""
        if self.visibility is None or len(self.images) == 0:
            p = int(np.asarray(positions).reshape(-1, 3).shape[0])
            return [np.zeros(0, dtype=np.int32) for _ in range(p)], np.full(p, -1, dtype=np.int64)
        return self.visibility.images_observing(positions, max_range=max_range)

    def terrain_index(self, min_share: float = 0.5, dtype: type = np.int64) -> np.ndarray:
        """(N,) terrain class index of every point by majority vote (terrain_winners)."""
        return terrain_winners(self.terrain_votes, min_share, dtype)


def terrain_winners(
    votes: np.ndarray, min_share: float = 0.5, dtype: type = np.int64, chunk: int = 1 << 16
) -> np.ndarray:
    """(N,) terrain class index by majority vote of votes (N, T) (ties: the lowest index), -1 where
    no vote or the winner's share of the point's votes is below `min_share`. Computed in chunks of
    rows, one class column at a time (for a few classes, comparisons per column cost less than a
    row-wise argmax), so the temporaries cost memory for a chunk, not for the map; `dtype` must
    hold the class count."""
    out = np.full(len(votes), -1, dtype=dtype)
    if votes.ndim != 2 or votes.shape[1] == 0:
        return out
    for start in range(0, len(votes), chunk):
        part = votes[start : start + chunk]
        top = part[:, 0].astype(np.int64)
        best = np.zeros(len(part), dtype=dtype)
        total = top.copy()
        for column in range(1, part.shape[1]):
            count = part[:, column]
            total += count
            best[count > top] = column  # strictly greater: a tie keeps the lower class, as argmax does
            np.maximum(top, count, out=top)
        share = np.divide(top, total, out=np.zeros(len(part)), where=total > 0)
        out[start : start + chunk] = np.where((total > 0) & (share >= min_share), best, -1)
    return out


def ms_avg_norms(counts: sp.csr_matrix, bank: np.ndarray, chunk: int = 65536) -> np.ndarray:
    """(N,) float32 norms of the rows of counts (N, K) @ bank (K, D), in row chunks so no N x D
    array is built; 0 for rows without observations."""
    counts = counts.tocsr()
    n = counts.shape[0]  # pyright: ignore[reportOptionalSubscript]  # scipy leaves `shape` unannotated
    out = np.zeros(n, dtype=np.float32)
    # Only observed rows: most map points (ground, walls) have none, and each row's norm is computed
    # on its own, so leaving the empty ones out changes no value.
    observed = np.flatnonzero(np.diff(counts.indptr))
    bank = np.asarray(bank)
    if bank.shape[0] <= bank.shape[1]:
        # Fewer bank entries than dimensions (the usual live map): |c B|^2 = c (B B^T) c, with the
        # K x K Gram matrix, costs K per stored count instead of D per observed point.
        gram = bank.astype(np.float64) @ bank.astype(np.float64).T
        for start in range(0, observed.size, chunk):
            rows = counts[observed[start : start + chunk]].astype(np.float64)
            squared = np.asarray(rows.multiply(rows @ gram).sum(axis=1)).ravel()
            out[observed[start : start + chunk]] = np.sqrt(np.maximum(squared, 0.0))
        return out
    for start in range(0, observed.size, chunk):
        rows = observed[start : start + chunk]
        out[rows] = np.linalg.norm(counts[rows] @ bank, axis=1)
    return out


def ms_max_ids(counts: sp.csr_matrix) -> np.ndarray:
    """(N,) int64 column of each row's largest count (ties: lowest column); -1 for empty rows."""
    counts = counts.tocsr()
    n = counts.shape[0]  # pyright: ignore[reportOptionalSubscript]  # scipy leaves `shape` unannotated
    indptr, indices, data = np.asarray(counts.indptr), np.asarray(counts.indices), np.asarray(counts.data)
    out = np.full(n, -1, dtype=np.int64)
    nnz = np.diff(indptr)
    rows = np.flatnonzero(nnz)
    if rows.size:
        # Sort each row's entries by (row, -count, id) and take the first per row.
        row_of = np.repeat(np.arange(n), nnz)
        order = np.lexsort((indices, np.negative(data), row_of))
        out[rows] = indices[order[indptr[rows]]]
    return out
