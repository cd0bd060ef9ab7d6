"""Neighbour searches (terra.neighbours): the direct computation for small inputs gives
SciPy's k-d tree answers, which the large inputs use."""

import numpy as np
import pytest
from scipy.spatial import KDTree

from terra import neighbours
from terra.neighbours import nearest, pairs_within


@pytest.mark.parametrize("seed", range(6))
def test_direct_pairs_and_nearest_equal_the_kd_tree(seed, monkeypatch):
    rng = np.random.default_rng(seed)
    points = rng.uniform(0, 10, (int(rng.integers(2, 600)), 3))
    if seed % 2:
        points = np.round(points / 0.4) * 0.4  # gridded: many equal distances
    radius = float(rng.uniform(0.3, 2.0))
    expected = {tuple(p) for p in KDTree(points).query_pairs(radius, output_type="ndarray").tolist()}
    assert {tuple(p) for p in pairs_within(points, radius).tolist()} == expected
    reference, queries = rng.uniform(0, 10, (50, 2)), rng.uniform(-2, 12, (200, 2))
    dist, index = KDTree(reference).query(queries, k=1, distance_upper_bound=1.0)
    got_dist, got_index = nearest(reference, queries, 1.0)
    np.testing.assert_array_equal(got_index, index)
    np.testing.assert_allclose(got_dist, dist, rtol=1e-12)
    monkeypatch.setattr(neighbours, "DIRECT_LIMIT", 0)  # the k-d tree path itself
    assert {tuple(p) for p in pairs_within(points, radius).tolist()} == expected
    np.testing.assert_array_equal(nearest(reference, queries, 1.0)[1], index)


def test_empty_inputs():
    assert pairs_within(np.zeros((0, 3)), 1.0).shape == (0, 2)
    assert pairs_within(np.zeros((1, 3)), 1.0).shape == (0, 2)
    dist, index = nearest(np.zeros((3, 2)), np.zeros((0, 2)))
    assert dist.shape == (0,) and index.shape == (0,)
