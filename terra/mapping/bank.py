"""The embedding bank: the distinct mask embeddings seen so far (paper: keep a new embedding only
if its cosine with every stored one is below 0.9).

A mask reuses the most similar entry when that cosine is at least `threshold`, otherwise it is
appended. Masks are matched in order against the bank as it grows, so near-duplicates within one
image share an entry too (the reference appended each of them).
"""

from __future__ import annotations

import numpy as np

from terra.mapping.association import grown


class EmbeddingBank:
    """K unit vectors of dimension D (float32), grown by `match_or_append`."""

    def __init__(self, dim: int, threshold: float = 0.9, vectors: np.ndarray | None = None):
        self.dim = int(dim)
        self.threshold = float(threshold)
        self._vectors = np.zeros((0, self.dim), dtype=np.float32)
        self.size = 0
        if vectors is not None and len(vectors):
            self._vectors = np.array(vectors, dtype=np.float32).reshape(-1, self.dim)
            self.size = self._vectors.shape[0]

    @property
    def vectors(self) -> np.ndarray:
        """(K, D) float32 view of the entries."""
        return self._vectors[: self.size]

    def __len__(self) -> int:
        return self.size

    def match_or_append(self, embeddings: np.ndarray) -> np.ndarray:
        """Bank id (M,) for each unit embedding (M, D), matched in order; ties take the lowest id."""
        embeddings = np.asarray(embeddings, dtype=np.float32).reshape(-1, self.dim)
        ids = np.empty(embeddings.shape[0], dtype=np.int64)
        if embeddings.shape[0] == 0:
            return ids
        existing = self.size
        if existing:
            sims = embeddings @ self.vectors.T
            best = sims.argmax(axis=1)
            best_sim = sims[np.arange(len(best)), best]
        else:
            best = np.full(embeddings.shape[0], -1)
            best_sim = np.full(embeddings.shape[0], -np.inf, dtype=np.float32)
        for m in range(embeddings.shape[0]):  # per mask (tens per image), not per point
            bid, bsim = int(best[m]), float(best_sim[m])
            if self.size > existing:  # entries appended earlier in this call
                added = self._vectors[existing : self.size] @ embeddings[m]
                j = int(added.argmax())
                if added[j] > bsim:
                    bid, bsim = existing + j, float(added[j])
            if bsim >= self.threshold:
                ids[m] = bid
            else:
                self._vectors = grown(self._vectors, self.size + 1)
                self._vectors[self.size] = embeddings[m]
                ids[m] = self.size
                self.size += 1
        return ids
