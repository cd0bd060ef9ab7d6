"""The visibility index (terra/mapping/visibility.py): its CSR against a reference built with NumPy's
row-wise unique, the index grown image by image against the index built at once, and a query
worked by hand."""

from __future__ import annotations

import numpy as np
import pytest

from terra.geometry import voxel_keys
from terra.mapping.visibility import VisibilityIndex, merged_pairs, sorted_pairs


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


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_an_index_grown_by_the_images_added_since_equals_the_index_built_at_once(seed):
    """A live map's fusion merges each version's new images into the sorted pairs of the images before
    (MapFusion.visibility_index); on random cells seen by growing runs of images, each merge equals
    the pairs of every image so far sorted in one go, shared cells and empty images included."""
    rng = np.random.default_rng(seed)
    per_image = [
        np.unique(rng.integers(-30, 30, rng.integers(0, 40)) * (1 << 21) + rng.integers(0, 3)) for _ in range(60)
    ]
    grown = (np.zeros(0, np.int64), np.zeros(0, np.int32))
    done = 0
    for stop in (1, 2, 9, 9, 30, 60):  # two calls without new images among them
        lengths = [c.size for c in per_image[done:stop]]
        cells = np.concatenate(per_image[done:stop]) if stop > done else np.zeros(0, np.int64)
        grown = merged_pairs(grown, sorted_pairs(cells, np.repeat(np.arange(done, stop), lengths)))
        done = stop
        everything = np.concatenate(per_image[:stop])
        at_once = sorted_pairs(everything, np.repeat(np.arange(stop), [c.size for c in per_image[:stop]]))
        np.testing.assert_array_equal(grown[0], at_once[0])
        np.testing.assert_array_equal(grown[1], at_once[1])
        reference = np.unique(
            np.column_stack([everything, np.repeat(np.arange(stop), [c.size for c in per_image[:stop]])]), axis=0
        )
        np.testing.assert_array_equal(np.column_stack(grown).reshape(-1, 2), reference)


def test_the_fusions_index_grown_over_a_drive_equals_the_index_of_all_its_pairs(tiny_campus, tmp_path):
    from terra.live import Session

    session = Session(tmp_path / "live.terra", tiny_campus.classes, graph=False)
    for i in range(6):
        session.add(tiny_campus[i])
        if i % 2:
            fusion = session.mapper.fusion
            images = fusion.image_table()
            grown = fusion.visibility_index(images.position)
            cells, image_ids = fusion.visibility_pairs()
            at_once = VisibilityIndex.from_pairs(cells, image_ids, grown.cell_size, images.position)
            for name in ("cell_keys", "indptr", "images"):
                np.testing.assert_array_equal(getattr(grown, name), getattr(at_once, name))
            assert grown.nnz > 0


def test_a_query_finds_the_images_that_saw_its_cell_within_range():
    # Image 0 at the origin and image 1 30 m away saw the cell at (1, 1, 0); image 2 saw another cell.
    positions = np.array([[0.0, 0.0, 0.0], [30.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    seen = voxel_keys(np.array([[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [50.0, 50.0, 0.0]]), 1.0)
    index = VisibilityIndex.from_pairs(seen, np.array([1, 0, 2]), 1.0, positions)
    lists, nearest = index.images_observing(np.array([[1.2, 1.3, 0.1]]), max_range=20.0)
    assert lists[0].tolist() == [0] and nearest.tolist() == [0]
