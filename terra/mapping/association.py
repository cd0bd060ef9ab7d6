"""Scan point -> global map point association (DESIGN.md decision 3).

Two kinds of global map:
- VoxelMap: built from the scans themselves. Every scan point falls in a voxel (edge
  `voxel_size` metres) found through a sorted voxel-key hash; a new voxel becomes a new map point,
  positioned at the centroid of all scan points that fell in it. A scan point is thus never
  associated farther than one voxel diagonal.
- FixedMap: the dataset's own global map (e.g. LIO-SAM's). Each scan point takes its nearest map
  point if it lies within `gate` metres, and none (-1) otherwise; nothing is matched across the map.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree  # pyright: ignore[reportAttributeAccessIssue]  # stubless compiled scipy module

from terra.geometry import voxel_keys


def grown(array: np.ndarray, size: int) -> np.ndarray:
    """`array` with room for at least `size` rows (capacity doubles; new rows are zero)."""
    if array.shape[0] >= size:
        return array
    out = np.zeros((max(size, 2 * array.shape[0], 1024), *array.shape[1:]), dtype=array.dtype)
    out[: array.shape[0]] = array
    return out


class VoxelMap:
    """A global map accumulated from posed scans, one point per occupied voxel."""

    def __init__(self, voxel_size: float):
        self.voxel_size = float(voxel_size)
        self.size = 0
        self._keys = np.zeros(0, dtype=np.int64)  # per map point, creation order
        self._sums = np.zeros((0, 3), dtype=np.float64)
        self._hits = np.zeros(0, dtype=np.int64)
        self._sorted_keys = np.zeros(0, dtype=np.int64)
        self._sorted_index = np.zeros(0, dtype=np.int64)

    def associate(self, points_map: np.ndarray) -> np.ndarray:
        """Map point index (n,) of each scan point (n, 3, metres, map frame), adding new voxels."""
        keys = voxel_keys(points_map, self.voxel_size)
        uniq, inverse = np.unique(keys, return_inverse=True)
        pos = np.searchsorted(self._sorted_keys, uniq)
        found = pos < self._sorted_keys.size
        found[found] = self._sorted_keys[pos[found]] == uniq[found]
        index_of = np.empty(uniq.size, dtype=np.int64)
        index_of[found] = self._sorted_index[pos[found]]
        new = np.flatnonzero(~found)
        index_of[new] = self.size + np.arange(new.size)
        self._sorted_keys = np.insert(self._sorted_keys, pos[new], uniq[new])
        self._sorted_index = np.insert(self._sorted_index, pos[new], index_of[new])
        n_new = self.size + new.size
        self._keys = grown(self._keys, n_new)
        self._sums = grown(self._sums, n_new)
        self._hits = grown(self._hits, n_new)
        self._keys[index_of[new]] = uniq[new]
        self.size = n_new
        for axis in range(3):
            self._sums[index_of, axis] += np.bincount(inverse, weights=points_map[:, axis], minlength=uniq.size)
        self._hits[index_of] += np.bincount(inverse, minlength=uniq.size)
        return index_of[inverse]

    def final_order(self) -> np.ndarray:
        """Permutation listing map points by voxel key: the stored order, independent of the
        order in which voxels were first seen. The key index keeps it already (keys are unique, so
        it is argsort(keys)); read-only, as every later insertion makes a new array."""
        order = self._sorted_index[: self.size]
        order.flags.writeable = False
        return order

    def points(self) -> np.ndarray:
        """(N, 3) float32 voxel centroids in creation order, metres, map frame."""
        return (self._sums[: self.size] / self._hits[: self.size, None]).astype(np.float32)

    def state(self, order: np.ndarray | slice | None = None) -> dict[str, np.ndarray]:
        """Voxel keys (N,) int64, coordinate sums (N, 3) float64 metres and hits (N,) int64, copies
        in creation order, or in `order` (e.g. final_order()) without a second copy; a slice of
        rows gives read-only views (valid until the next `associate`)."""
        rows = slice(0, self.size) if order is None else order
        keys, sums, hits = self._keys[rows], self._sums[rows], self._hits[rows]
        if order is None:
            keys, sums, hits = keys.copy(), sums.copy(), hits.copy()
        elif isinstance(order, slice):
            for view in (keys, sums, hits):
                view.flags.writeable = False
        return {"keys": keys, "sums": sums, "hits": hits}

    @classmethod
    def from_state(cls, voxel_size: float, state: dict[str, np.ndarray]) -> VoxelMap:
        vm = cls(voxel_size)
        vm._keys = np.array(state["keys"], dtype=np.int64)
        vm._sums = np.array(state["sums"], dtype=np.float64)
        vm._hits = np.array(state["hits"], dtype=np.int64)
        vm.size = int(vm._keys.size)
        order = np.argsort(vm._keys, kind="stable")
        vm._sorted_keys, vm._sorted_index = vm._keys[order], order.astype(np.int64)
        return vm


class FixedMap:
    """A given global map (M, 3); association by nearest neighbour within `gate` metres."""

    def __init__(self, points: np.ndarray, gate: float):
        self._points = np.ascontiguousarray(points, dtype=np.float32)
        self.gate = float(gate)
        self.size = int(self._points.shape[0])
        self._tree = cKDTree(self._points.astype(np.float64))

    def associate(self, points_map: np.ndarray) -> np.ndarray:
        """Index (n,) of the nearest map point within the gate, -1 where none is."""
        dist, index = self._tree.query(points_map, k=1, distance_upper_bound=self.gate)
        return np.where(np.isfinite(dist), index, -1).astype(np.int64)

    def final_order(self) -> np.ndarray:
        return np.arange(self.size)

    def points(self) -> np.ndarray:
        return self._points
