"""The visibility index (terra/mapping/visibility.py): its CSR against a reference built with NumPy's
row-wise unique, and a query worked by hand."""

from __future__ import annotations

import numpy as np
import pytest

from terra.geometry import voxel_keys
from terra.mapping.visibility import VisibilityIndex


@pytest.mark.parametrize("n", [0, 1, 7, 5000])
def test_the_index_holds_each_cells_images_once_in_order(n):
    rng = np.random.default_rng(n)
    cells = rng.integers(-40, 40, n) * (1 << 42) + rng.integers(0, 9, n)  # negative and large keys
    images = rng.integers(0, 25, n)
    cells, images = np.concatenate([cells, cells[: n // 2]]), np.concatenate([images, images[: n // 2]])
    index = VisibilityIndex.from_pairs(cells, images, 0.5, np.zeros((25, 3)))
    pairs = np.unique(np.column_stack([cells, images]), axis=0).reshape(-1, 2)
    keys, start, counts = np.unique(pairs[:, 0], return_index=True, return_counts=True)
    np.testing.assert_array_equal(index.cell_keys, keys)
    np.testing.assert_array_equal(index.indptr, np.append(start, len(pairs)))
    np.testing.assert_array_equal(np.diff(index.indptr), counts)
    np.testing.assert_array_equal(index.images, pairs[:, 1])
    assert index.cell_keys.dtype == np.int64 and index.indptr.dtype == np.int64 and index.images.dtype == np.int32


def test_a_query_finds_the_images_that_saw_its_cell_within_range():
    # Image 0 at the origin and image 1 30 m away saw the cell at (1, 1, 0); image 2 saw another cell.
    positions = np.array([[0.0, 0.0, 0.0], [30.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    seen = voxel_keys(np.array([[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [50.0, 50.0, 0.0]]), 1.0)
    index = VisibilityIndex.from_pairs(seen, np.array([1, 0, 2]), 1.0, positions)
    lists, nearest = index.images_observing(np.array([[1.2, 1.3, 0.1]]), max_range=20.0)
    assert lists[0].tolist() == [0] and nearest.tolist() == [0]
