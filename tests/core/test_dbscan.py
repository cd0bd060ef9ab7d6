"""DBSCAN on SciPy (terra.dbscan) against scikit-learn's, the reference it replaces on the
query path: the same labels on random, voxel-gridded and duplicated point sets."""

import numpy as np
import pytest
from sklearn.cluster import DBSCAN

from terra.dbscan import dbscan_labels


@pytest.mark.parametrize("seed", range(12))
def test_labels_equal_scikit_learn(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 2500))
    points = rng.uniform(0, rng.uniform(3, 40), (n, 3))
    if seed % 3 == 0:  # voxel centres, as map points are: many equal distances
        points = np.round(points / 0.4) * 0.4
    if seed % 4 == 1:  # duplicates
        points = np.vstack([points, points[: n // 3]])
    eps, min_samples = float(rng.uniform(0.3, 2.0)), int(rng.integers(1, 10))
    expected = DBSCAN(eps=eps, min_samples=min_samples).fit_predict(points)
    np.testing.assert_array_equal(dbscan_labels(points, eps, min_samples), expected)


def test_border_point_joins_the_first_cluster_and_small_inputs():
    # Two groups of 6 points (0.05 m apart, all core) and a point between them 0.875 m from one
    # edge point of each: a border point of both, which scikit-learn gives to the cluster it
    # expands first (the one with the lowest core index).
    left = np.column_stack([np.arange(6) * 0.05, np.zeros(6), np.zeros(6)])
    right = left + [2.0, 0, 0]
    between = np.array([[1.125, 0, 0]])
    points = np.vstack([right, left, between])  # right first: it is cluster 0
    labels = dbscan_labels(points, eps=0.9, min_samples=6)
    assert labels.tolist() == [0] * 6 + [1] * 6 + [0]
    assert labels.tolist() == DBSCAN(eps=0.9, min_samples=6).fit_predict(points).tolist()
    flipped = np.vstack([left, right, between])
    assert dbscan_labels(flipped, eps=0.9, min_samples=6).tolist() == [0] * 6 + [1] * 6 + [0]
    assert dbscan_labels(np.zeros((0, 3)), 1.0, 4).shape == (0,)
    assert dbscan_labels(np.zeros((3, 3)), 1.0, 4).tolist() == [-1, -1, -1]


@pytest.mark.parametrize("seed", range(8))
def test_weighted_labels_equal_scikit_learn(seed):
    """Phase 1's use: voxel-merged mask points as weighted samples, masks apart in a fourth
    coordinate (terra.mapping.clustering)."""
    rng = np.random.default_rng(100 + seed)
    n = int(rng.integers(1, 3000))
    points = np.round(rng.uniform(0, rng.uniform(3, 30), (n, 3)) / 0.2) * 0.2
    eps = float(rng.uniform(0.3, 2.0))
    points = np.column_stack([points, rng.integers(0, 5, n) * 3.0 * eps])
    weight = rng.integers(1, 40, n).astype(np.float64)
    min_samples = int(rng.integers(1, 60))
    expected = DBSCAN(eps=eps, min_samples=min_samples).fit_predict(points, sample_weight=weight)
    np.testing.assert_array_equal(dbscan_labels(points, eps, min_samples, sample_weight=weight), expected)
