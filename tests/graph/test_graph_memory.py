"""The narrow-memory helpers of the build give what the plain NumPy/SciPy calls give."""

import numpy as np
import scipy.sparse as sp

from terra.graph.embedding import unique_cells
from terra.graph.gvd import EIGHT, component_sizes, label_components
from terra.mapping.semantic_map import ImageTable, MetricSemanticMap, terrain_winners
from tests.graph.fixtures import label_parts


def test_unique_cells_equals_numpy_unique_by_rows():
    rng = np.random.default_rng(3)
    for n in (1, 7, 400):
        cells = rng.integers(-40, 40, (n, 2)).astype(np.int64)
        keys, inverse = np.unique(cells, axis=0, return_inverse=True)
        got_keys, got_inverse = unique_cells(cells)
        assert np.array_equal(got_keys, keys)
        assert np.array_equal(got_inverse, inverse.ravel())
        assert np.array_equal(got_keys[got_inverse], cells)


def test_label_components_is_uint16_when_the_labels_fit_and_int32_beyond():
    few = np.zeros((20, 20), bool)
    few[2:5, 2:5] = few[10:12, 14:18] = True
    labels, n = label_components(few)
    expected, m = label_parts(few, EIGHT)
    assert labels.dtype == np.uint16 and n == m == 2 and np.array_equal(labels, expected)
    many = np.zeros((600, 600), bool)
    many[::2, ::2] = True  # 90,000 isolated cells: more than uint16 can number
    labels, n = label_components(many)
    assert labels.dtype == np.int32 and n == 90_000
    assert np.array_equal(labels, label_parts(many, EIGHT)[0])


def test_component_sizes_count_every_label_across_row_blocks():
    rng = np.random.default_rng(4)
    labels = rng.integers(0, 9, (37, 11)).astype(np.uint16)
    assert np.array_equal(component_sizes(labels, 8, rows=5), np.bincount(labels.ravel(), minlength=9))


def test_terrain_index_in_chunks_equals_the_hand_worked_majority():
    votes = np.array([[0, 0, 0], [3, 1, 0], [1, 1, 0], [0, 2, 2], [0, 0, 5], [2, 1, 1]], dtype=np.uint16)
    n = len(votes)
    images = ImageTable(np.zeros(0), np.zeros(0, np.int16), np.zeros((0, 4, 4)), np.zeros((0, 3), np.float32))
    msm = MetricSemanticMap(
        points=np.zeros((n, 3), np.float32),
        terrain_classes=["a", "b", "c"],
        terrain_votes=votes,
        terrain_embeddings=np.eye(3, dtype=np.float32),
        counts=sp.csr_matrix((n, 2), dtype=np.int32),
        bank=np.eye(2, 3, dtype=np.float32),
        images=images,
        embedder="toy",
    )
    # winner share: -, 3/4, 1/2 (tie: lowest class), 1/2, 1, 1/2
    expected = [-1, 0, 0, 1, 2, 0]
    for chunk in (1, 4, 100):
        got = terrain_winners(msm.terrain_votes, 0.5, dtype=np.int16, chunk=chunk)
        assert got.dtype == np.int16 and got.tolist() == expected
    assert msm.terrain_index(0.6).tolist() == [-1, 0, -1, -1, 2, -1]


def test_grown_equals_binary_dilation_with_eight_neighbours():
    from scipy import ndimage

    from terra.graph import raster

    rng = np.random.default_rng(5)
    for shape, cells in (((1, 1), 1), ((7, 3), 2), ((40, 55), 1), ((40, 55), 3), ((23, 31), 9)):
        mask = rng.random(shape) < 0.03
        mask[0, -1] = True  # a corner: nothing beyond the edge counts
        expected = ndimage.binary_dilation(mask, EIGHT, iterations=cells)
        assert np.array_equal(raster.grown(mask, cells), expected), (shape, cells)
    mask = rng.random((9, 9)) < 0.2
    assert raster.grown(mask, 0) is mask
