"""Fusion building blocks: association and its gate, the bank, DBSCAN, votes and counts."""

import numpy as np
from sklearn.cluster import DBSCAN

from terra.geometry import CameraCalibration, voxel_keys
from terra.mapping.association import FixedMap, VoxelMap
from terra.mapping.bank import EmbeddingBank
from terra.mapping.clustering import largest_clusters
from terra.mapping.config import MappingConfig
from terra.mapping.fusion import MapFusion
from terra.perception.base import ImagePerception
from terra.perception.masks import MaskSet


def unit(*v):
    v = np.asarray(v, dtype=np.float32)
    return v / np.linalg.norm(v)


def test_fixed_map_gate():
    grid = np.array([[0.0, 0, 0], [5.0, 0, 0], [10.0, 0, 0]])
    fixed = FixedMap(grid, gate=1.0)
    scan = np.array([[0.5, 0, 0], [5.0, 0.99, 0], [6.2, 0, 0], [7.6, 0, 0], [10.0, 0, 1.01]])
    assert fixed.associate(scan).tolist() == [0, 1, -1, -1, -1]
    assert FixedMap(grid, gate=3.0).associate(scan).tolist() == [0, 1, 1, 2, 2]


def test_voxel_map_centroids_and_stable_order():
    rng = np.random.default_rng(0)
    scans = [rng.uniform(-3, 3, (400, 3)) for _ in range(3)]
    vm = VoxelMap(0.5)
    indices = [vm.associate(s) for s in scans]
    pts = np.concatenate(scans)
    idx = np.concatenate(indices)
    keys = voxel_keys(pts, 0.5)
    # Same voxel <=> same map point, across scans.
    _, key_id = np.unique(keys, return_inverse=True)
    assert np.array_equal(np.unique(np.column_stack([key_id, idx]), axis=0)[:, 0], np.arange(key_id.max() + 1))
    # Each map point is the mean of its scan points (dense reference).
    centroids = np.stack([pts[idx == i].mean(axis=0) for i in range(vm.size)])
    np.testing.assert_allclose(vm.points(), centroids, atol=1e-5)
    # Stored order is by voxel key, whatever order the voxels were met in.
    order = vm.final_order()
    assert np.all(np.diff(voxel_keys(vm.points()[order].astype(np.float64), 0.5)) > 0)
    again = VoxelMap(0.5)
    for s in scans[::-1]:
        again.associate(s)
    np.testing.assert_allclose(again.points()[again.final_order()], vm.points()[order], atol=1e-5)
    # State round trip keeps associating identically.
    restored = VoxelMap.from_state(0.5, vm.state())
    probe = rng.uniform(-4, 4, (300, 3))
    assert np.array_equal(restored.associate(probe), vm.associate(probe))


def test_bank_reuses_entries_at_09_and_dedups_within_one_image():
    bank = EmbeddingBank(3, threshold=0.9)
    a, b = unit(1, 0, 0), unit(0, 1, 0)
    a91 = unit(0.91, np.sqrt(1 - 0.91**2), 0)  # cos(a, a91) = 0.91
    a89 = unit(0.89, 0, np.sqrt(1 - 0.89**2))  # cos(a, a89) = 0.89
    assert bank.match_or_append(np.stack([a, a91, b, a89, a])).tolist() == [0, 0, 1, 2, 0]
    assert len(bank) == 3
    # Later images: the best match at or above 0.9 wins.
    assert bank.match_or_append(np.stack([b, a89, unit(0, 0, 1)])).tolist() == [1, 2, 3]
    # A mask closer to an entry appended earlier in the same call than to an old one picks it.
    bank2 = EmbeddingBank(2, threshold=0.9, vectors=unit(1, 0)[None])
    c = unit(0.92, np.sqrt(1 - 0.92**2))  # cos with entry 0: 0.92
    d = unit(0.80, np.sqrt(1 - 0.80**2))  # cos with entry 0: 0.80 -> new; cos(c, d) ~ 0.98
    assert bank2.match_or_append(np.stack([d, c])).tolist() == [1, 1]


def test_largest_cluster_per_group_equals_one_dbscan_per_group():
    rng = np.random.default_rng(3)
    blob = lambda centre, n: rng.normal(centre, 0.3, (n, 3))  # noqa: E731
    pts = np.concatenate(
        [blob([0, 0, 0], 12), blob([10, 0, 0], 7), [[30, 0, 0], [40, 0, 0]], blob([10, 0, 0], 9), blob([0, 5, 0], 3)]
    )
    group = np.array([0] * 12 + [0] * 7 + [0, 0] + [4] * 9 + [7] * 3)
    keep = largest_clusters(pts, group, eps=1.0, min_samples=4)
    expected = np.zeros(len(pts), bool)
    for g in np.unique(group):
        sel = np.flatnonzero(group == g)
        labels = DBSCAN(eps=1.0, min_samples=4).fit_predict(pts[sel])
        if (labels >= 0).any():
            expected[sel[labels == np.bincount(labels[labels >= 0]).argmax()]] = True
    np.testing.assert_array_equal(keep, expected)
    assert keep[:12].all() and not keep[12:21].any() and keep[21:30].all() and not keep[30:].any()


def test_a_facade_mask_is_merged_on_wider_voxels_and_keeps_the_same_cluster():
    """A 15 x 5 m wall seen at 0.14 m spacing (1,875 samples on 0.2 m voxels: more than MAX_SAMPLES) and
    mask bleed 4 m in front of it: the wall is sampled on 0.4 m voxels, and the wall alone is kept, as
    scikit-learn's DBSCAN on every raw point keeps it."""
    from terra.mapping.clustering import MAX_SAMPLES, _voxel_samples

    u, v = np.meshgrid(np.arange(0.0, 15.0, 0.14), np.arange(0.0, 5.0, 0.14))
    wall = np.column_stack([u.ravel(), np.full(u.size, 10.0), v.ravel()])
    bleed = np.random.default_rng(5).normal([7.0, 6.0, 0.2], 0.2, (40, 3))
    pts = np.vstack([wall, bleed])
    group = np.zeros(len(pts), dtype=np.int64)
    narrow, _ = _voxel_samples(wall, group[: len(wall)], 0.2, max_samples=0)
    wide, _ = _voxel_samples(wall, group[: len(wall)], 0.2)
    assert narrow.max() + 1 > MAX_SAMPLES >= wide.max() + 1
    keep = largest_clusters(pts, group, eps=2.0, min_samples=5, voxel=0.2)
    labels = DBSCAN(eps=2.0, min_samples=5).fit_predict(pts)
    np.testing.assert_array_equal(keep, labels == np.bincount(labels[labels >= 0]).argmax())
    assert keep[: len(wall)].all() and not keep[len(wall) :].any()


def _identity_camera(width=20, height=10):
    # Camera frame = LiDAR frame; f = 10 px, centre (10, 5): point (x, y, 10) -> pixel (5 + y, 10 + x).
    return CameraCalibration("cam", width, height, np.array([[10, 0, 10], [0, 10, 5], [0, 0, 1]]))


def test_votes_and_one_count_per_point_entry_and_image():
    config = MappingConfig.model_validate({"fusion": {"dbscan_min_samples": 1, "dbscan_eps": 1.5, "voxel_size": 0.4}})
    fusion = MapFusion(config, ["grass", "asphalt"], dim=2)
    cam = _identity_camera()
    # Four scan points at depth 10 m on pixels (5, 10), (5, 11), (6, 10), (8, 15); the first two in
    # one voxel (they become one map point).
    pts = np.array([[0.0, 0.0, 10.0], [0.1, 0.0, 10.0], [0.0, 1.0, 10.0], [5.0, 3.0, 10.0]], np.float32)
    T = np.eye(4)
    pts_map, index = fusion.associate(pts, T)
    assert index[0] == index[1] and len(set(index.tolist())) == 3
    terrain = np.full((10, 20), -1, np.int16)
    terrain[8, 15] = 1  # asphalt under point 3
    stack = np.zeros((3, 10, 20), bool)
    stack[0, 5:7, 10:12] = True  # object A: points 0, 1, 2
    stack[1, 5, 10:12] = True  # same embedding as A (a duplicate mask): points 0, 1
    stack[2, 7:10, 14:17] = True  # 3x3 box around point 3: 1/9 on terrain, so the mask is kept
    emb = np.stack([unit(1, 0), unit(1, 0), unit(0, 1)])
    seen = ImagePerception(terrain, MaskSet.from_stack(stack), emb, unit(1, 1))
    fusion.integrate_image(pts, pts_map, index, T, cam, 0.0, seen)
    fusion.integrate_image(pts, pts_map, index, T, cam, 0.1, seen)
    msm = fusion.finish("toy", np.eye(2, dtype=np.float32))
    row = {i: int(np.flatnonzero(np.all(np.isclose(msm.points, pts_map[i], atol=0.06), axis=1))[0]) for i in (0, 2, 3)}
    dense = msm.counts.toarray()
    # Two images, each adds one count per (point, entry): not per pixel, not per duplicate mask.
    assert dense[row[0]].tolist() == [2] and dense[row[2]].tolist() == [2]
    assert dense[row[3]].tolist() == [0]  # point 3 lies on terrain: not an object point
    assert msm.terrain_votes[row[3]].tolist() == [0, 2] and msm.terrain_votes.sum() == 2
    # The third mask has no point off terrain, so nothing survives DBSCAN and it adds no entry.
    assert msm.bank.shape == (1, 2) and fusion.stats.counts["masks_dropped_dbscan"] == 2
    assert len(msm.images) == 2


def test_masks_mostly_on_terrain_are_dropped():
    config = MappingConfig.model_validate({"fusion": {"dbscan_min_samples": 1}})
    fusion = MapFusion(config, ["grass"], dim=2)
    cam = _identity_camera()
    pts = np.array([[0.0, 0.0, 10.0], [1.0, 0.0, 10.0]], np.float32)
    pts_map, index = fusion.associate(pts, np.eye(4))
    terrain = np.full((10, 20), -1, np.int16)
    terrain[5, 12:14] = 0
    stack = np.zeros((2, 10, 20), bool)
    stack[0, 5, 10:14] = True  # 2 of 4 pixels on terrain: kept (at most 50 %)
    stack[1, 5, [10, 12, 13]] = True  # 2 of 3 pixels on terrain: dropped
    seen = ImagePerception(terrain, MaskSet.from_stack(stack), np.stack([unit(1, 0), unit(0, 1)]), unit(1, 0))
    fusion.integrate_image(pts, pts_map, index, np.eye(4), cam, 0.0, seen)
    assert fusion.stats.counts["masks_dropped_terrain"] == 1
    assert len(fusion.bank) == 1 and np.allclose(fusion.bank.vectors[0], unit(1, 0))
