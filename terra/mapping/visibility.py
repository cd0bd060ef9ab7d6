"""Which images saw which part of the map, for Phase 2's "images within 20 m that saw a place".

During fusion every image records the visibility cells (voxels of `cell_size` metres) holding the
scan points it saw (after the z-buffer, so occluded points do not count). The index stores, per
occupied cell, the sorted list of images (CSR). A query position looks at its cell and the cells
around it (a cube of `radius_cells` cells each way), keeps the images whose camera centre is
within `max_range` of the position, and reports the nearest image at any range. Distances are
measured from the camera centre, not from the LiDAR (the reference used the LiDAR range).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from terra.geometry import voxel_keys


@dataclass
class VisibilityIndex:
    """cell_keys: (C,) sorted int64 voxel keys (terra.geometry.voxel_keys at cell_size).
    indptr: (C+1,) int64; images: (nnz,) int32 image indices, ascending within each cell.
    image_positions: (M, 3) camera centres in the map frame, metres."""

    cell_size: float
    cell_keys: np.ndarray
    indptr: np.ndarray
    images: np.ndarray
    image_positions: np.ndarray

    @classmethod
    def from_pairs(
        cls, cell_keys: np.ndarray, image_ids: np.ndarray, cell_size: float, image_positions: np.ndarray
    ) -> VisibilityIndex:
        """Index from (cell key, image) observation pairs (duplicates allowed)."""
        cells, images = sorted_pairs(cell_keys, image_ids)
        return cls.from_sorted_pairs(cells, images, cell_size, image_positions)

    @classmethod
    def from_sorted_pairs(
        cls, cells: np.ndarray, images: np.ndarray, cell_size: float, image_positions: np.ndarray
    ) -> VisibilityIndex:
        """Index from unique (cell key, image) pairs sorted by cell, then image (`sorted_pairs`)."""
        new_cell = np.ones(cells.size, dtype=bool)
        new_cell[1:] = cells[1:] != cells[:-1]
        indptr = np.append(np.flatnonzero(new_cell), cells.size).astype(np.int64)
        return cls(
            float(cell_size),
            cells[new_cell],
            indptr,
            np.asarray(images, dtype=np.int32),  # shared with the fusion's sorted pairs: never written
            np.asarray(image_positions, dtype=np.float64).reshape(-1, 3),
        )

    @property
    def nnz(self) -> int:
        return int(self.images.shape[0])

    def _neighbour_keys(self, positions: np.ndarray, radius_cells: int) -> np.ndarray:
        """(P, n_offsets) keys of the cells around each position."""
        r = np.arange(-radius_cells, radius_cells + 1)
        offsets = np.stack(np.meshgrid(r, r, r, indexing="ij"), axis=-1).reshape(-1, 3)
        centre = voxel_keys(positions, self.cell_size)
        # voxel_keys packs x, y, z into 21-bit fields: adding packed offsets moves between cells.
        packed = (offsets[:, 0] << 42) + (offsets[:, 1] << 21) + offsets[:, 2]
        return centre[:, None] + packed[None, :]

    def images_observing(
        self, positions: np.ndarray, max_range: float = 20.0, radius_cells: int = 1, chunk: int = 4096
    ) -> tuple[list[np.ndarray], np.ndarray]:
        """Per position (P, 3, metres, map frame): the indices of images whose camera centre was
        within `max_range` metres of it and that saw its neighbourhood (sorted), and (P,) the
        nearest image that saw it at any range (-1 if none)."""
        positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
        lists: list[np.ndarray] = []
        nearest = np.full(positions.shape[0], -1, dtype=np.int64)
        for start in range(0, positions.shape[0], chunk):
            block = positions[start : start + chunk]
            pos_idx, img = self._candidates(block, radius_cells)
            dist = np.linalg.norm(self.image_positions[img] - block[pos_idx], axis=1)
            # Nearest at any range: first pair per position in (position, distance, image) order.
            order = np.lexsort((img, dist, pos_idx))
            first = np.ones(order.size, dtype=bool)
            first[1:] = pos_idx[order[1:]] != pos_idx[order[:-1]]
            nearest[start + pos_idx[order[first]]] = img[order[first]]
            near = dist <= max_range
            pos_near, img_near = pos_idx[near], img[near]
            bounds = np.searchsorted(pos_near, np.arange(block.shape[0] + 1))
            lists.extend(img_near[bounds[i] : bounds[i + 1]] for i in range(block.shape[0]))
        return lists, nearest

    def _candidates(self, block: np.ndarray, radius_cells: int) -> tuple[np.ndarray, np.ndarray]:
        """Unique (position, image) pairs, sorted by position then image."""
        keys = self._neighbour_keys(block, radius_cells)
        slot = np.searchsorted(self.cell_keys, keys)
        slot_c = np.minimum(slot, max(self.cell_keys.size - 1, 0))
        hit = (
            (slot < self.cell_keys.size) & (self.cell_keys[slot_c] == keys)
            if self.cell_keys.size
            else np.zeros(keys.shape, bool)
        )
        pos_idx = np.repeat(np.arange(block.shape[0]), keys.shape[1])[hit.ravel()]
        cells = slot_c.ravel()[hit.ravel()]
        lengths = self.indptr[cells + 1] - self.indptr[cells]
        pos_rep = np.repeat(pos_idx, lengths)
        # Positions of each cell's images in `images`: start of the run plus 0..length-1.
        run_start = np.repeat(self.indptr[cells] - np.cumsum(lengths) + lengths, lengths)
        img = self.images[run_start + np.arange(pos_rep.size)].astype(np.int64)
        pair = np.unique(pos_rep * max(int(self.image_positions.shape[0]), 1) + img)
        m = max(int(self.image_positions.shape[0]), 1)
        return pair // m, pair % m


def sorted_pairs(cell_keys: np.ndarray, image_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(cells (P,) int64, images (P,) int32): the unique (cell key, image) pairs, sorted by cell, then image."""
    cells, images = np.asarray(cell_keys, np.int64).ravel(), np.asarray(image_ids, np.int64).ravel()
    # One sort of two integer keys: a row-wise np.unique (a sort of void records) took 20x as long
    # (0.18 s of a 0.9 s campus snapshot).
    order = np.lexsort((images, cells))
    cells, images = cells[order], images[order]
    new_pair = np.ones(cells.size, dtype=bool)
    new_pair[1:] = (cells[1:] != cells[:-1]) | (images[1:] != images[:-1])
    return cells[new_pair], images[new_pair].astype(np.int32)


def merged_pairs(
    old: tuple[np.ndarray, np.ndarray], new: tuple[np.ndarray, np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    """`sorted_pairs` of the pairs `old` and `new` (each already sorted and unique), when every image
    of `new` is above every image of `old` (images added since): each new pair goes after the old
    pairs of its cell, so the merge costs a search of the new cells, not a sort of every pair (a
    live map's index grows by a few images between versions)."""
    (old_cells, old_images), (new_cells, new_images) = old, new
    at = np.searchsorted(old_cells, new_cells, side="right") + np.arange(new_cells.size)
    is_new = np.zeros(old_cells.size + new_cells.size, dtype=bool)
    is_new[at] = True
    cells, images = np.empty(is_new.size, np.int64), np.empty(is_new.size, np.int32)
    cells[is_new], images[is_new] = new_cells, new_images
    cells[~is_new], images[~is_new] = old_cells, old_images
    return cells, images
