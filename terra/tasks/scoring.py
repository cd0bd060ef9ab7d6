"""Per-point cosines with query vectors, one column at a time, for fast retrieval on large maps.

The map's features are never materialised (no points x dimension array): with s = bank @ v for a
unit vector v, the MS-Avg cosine of point i is (counts_i . s) / ||counts_i @ bank|| and the MS-Max
cosine is s[most observed bank id of i]. A scorer keeps a float32 copy of the counts and the
cached row norms, so each query column is one sparse matrix-vector product. The bank scores
s = bank @ v of recent vectors are kept too: the terrain names' vectors are the same for every
query on a map, and a robot repeats its questions.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from typing import Literal

import numpy as np
import scipy.sparse as sp

from terra.mapping.semantic_map import MetricSemanticMap

Feature = Literal["avg", "max"]
CACHED_SCORES = 256  # bank-score columns kept per scorer (K floats each)


class PointScorer:
    """Cosine similarity of a map's point features (MS-Avg or MS-Max) with unit vectors."""

    def __init__(self, msm: MetricSemanticMap):
        counts = msm.counts.tocsr()
        # float32 data: scipy would otherwise upcast int counts x float32 vectors to float64.
        self.counts = sp.csr_matrix((counts.data.astype(np.float32), counts.indices, counts.indptr), shape=counts.shape)
        norms = msm.ms_avg_norms()
        self.inv_norm = np.divide(1.0, norms, out=np.zeros_like(norms, dtype=np.float32), where=norms > 0).astype(
            np.float32
        )
        self.bank = np.asarray(msm.bank, dtype=np.float32)
        self._msm = msm
        self._max_ids: np.ndarray | None = None
        self._scores: OrderedDict[bytes, np.ndarray] = OrderedDict()
        self._lock = threading.Lock()

    @property
    def max_ids(self) -> np.ndarray:
        if self._max_ids is None:
            self._max_ids = self._msm.ms_max_ids()
        return self._max_ids

    def bank_scores(self, vectors: np.ndarray) -> np.ndarray:
        """(K, V) float32 cosines of the bank entries with unit vectors (V, D), per vector cached."""
        vectors = np.asarray(vectors, dtype=np.float32).reshape(-1, self.bank.shape[1])
        columns: list[np.ndarray | None] = []
        with self._lock:
            for v in vectors:
                column = self._scores.get(v.tobytes())
                if column is not None:
                    self._scores.move_to_end(v.tobytes())
                columns.append(column)
        missing = [i for i, c in enumerate(columns) if c is None]
        if missing:
            # One matrix-vector product per vector: a column's bits must not depend on which
            # other vectors shared the call (a matrix product may sum in another order).
            fresh = {i: self.bank @ vectors[i] for i in missing}
            with self._lock:
                for i, column in fresh.items():
                    columns[i] = column
                    self._scores[vectors[i].tobytes()] = column
                while len(self._scores) > CACHED_SCORES:
                    self._scores.popitem(last=False)
        filled = [c for c in columns if c is not None]  # every column, now that the missing ones are scored
        return np.stack(filled, axis=1) if filled else np.zeros((self.bank.shape[0], 0), dtype=np.float32)

    def observed(self) -> np.ndarray:
        """Indices of points with at least one observation."""
        return np.flatnonzero(np.diff(self.counts.indptr) > 0)

    def similarity(self, vectors: np.ndarray, feature: Feature = "avg", rows: np.ndarray | None = None) -> np.ndarray:
        """(n, V) float32 cosines of the points' features with unit vectors (V, D); 0 for
        unobserved points. rows: a subset of point indices (default all)."""
        s = self.bank_scores(vectors)  # (K, V)
        if feature == "avg":
            counts = self.counts if rows is None else self.counts[rows]
            inv = self.inv_norm if rows is None else self.inv_norm[rows]
            # One column: a matrix-vector product, measurably faster than the multi-vector kernel.
            num = (counts @ s[:, 0])[:, None] if s.shape[1] == 1 else counts @ s
            return np.asarray(num, dtype=np.float32) * inv[:, None]
        if feature != "max":
            raise ValueError(f"feature must be 'avg' or 'max', got {feature!r}")
        ids = self.max_ids if rows is None else self.max_ids[rows]
        out = s[np.maximum(ids, 0)]
        out[ids < 0] = 0.0
        return out
