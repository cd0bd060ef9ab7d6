"""The map's derived features against dense references, storage round trip, visibility queries."""

import numpy as np
import pytest
import scipy.sparse as sp

from terra.bundle import Bundle, BundleWriter
from terra.mapping.config import MappingConfig
from terra.mapping.pipeline import run_mapping
from terra.mapping.projection import visible_points
from terra.mapping.semantic_map import ImageTable, MetricSemanticMap
from terra.mapping.storage import load_map, write_map
from terra.perception.text import normalize_rows
from tests.mapping.fixtures import BoxScene


def random_map(rng, n=60, k=7, d=5) -> MetricSemanticMap:
    # scipy still takes random_state (a legacy RandomState stream) through a decorator that pyright does not see.
    counts = (
        sp.random(n, k, density=0.2, random_state=np.random.RandomState(1), data_rvs=lambda s: rng.integers(1, 5, s))  # pyright: ignore[reportCallIssue]
        .tocsr()
        .astype(np.int32)
    )
    return MetricSemanticMap(
        points=rng.normal(size=(n, 3)).astype(np.float32),
        terrain_classes=["grass"],
        terrain_votes=rng.integers(0, 3, (n, 1)).astype(np.uint16),
        terrain_embeddings=normalize_rows(rng.normal(size=(1, d))),
        counts=counts,
        bank=normalize_rows(rng.normal(size=(k, d))),
        images=ImageTable(np.zeros(0), np.zeros(0, np.int16), np.zeros((0, 4, 4)), np.zeros((0, d), np.float32)),
        embedder="toy",
    )


def dense_features(msm: MetricSemanticMap, queries: np.ndarray):
    """MS-Avg / MS-Max similarities the slow way: build every point's feature vector."""
    C = msm.counts.toarray().astype(np.float64)
    avg = C @ msm.bank
    norms = np.linalg.norm(avg, axis=1, keepdims=True)
    avg = np.divide(avg, norms, out=np.zeros_like(avg), where=norms > 0)
    best = np.array([np.flatnonzero(row == row.max())[0] if row.max() > 0 else -1 for row in C])
    mx = np.where(best[:, None] >= 0, msm.bank[np.maximum(best, 0)], 0.0)
    return avg @ queries.T, mx @ queries.T, best


def test_sparse_ms_avg_and_ms_max_equal_dense():
    rng = np.random.default_rng(0)
    msm = random_map(rng)
    queries = normalize_rows(rng.normal(size=(3, 5)))
    avg, mx, best = dense_features(msm, queries)
    np.testing.assert_allclose(msm.ms_avg_similarity(queries), avg, atol=1e-5)
    np.testing.assert_allclose(msm.ms_max_similarity(queries), mx, atol=1e-5)
    np.testing.assert_array_equal(msm.ms_max_ids(), best)
    rows = np.array([5, 0, 17])
    np.testing.assert_allclose(msm.ms_avg_similarity(queries, rows), avg[rows], atol=1e-5)


def test_storage_round_trip(tmp_path):
    rng = np.random.default_rng(2)
    msm = random_map(rng)
    writer = BundleWriter(tmp_path / "m.terra")
    write_map(writer, msm, config={"x": 1}, stats={"frames_fused": 3}, dataset="toy")
    bundle = writer.commit()
    assert bundle.manifest["embedder"] == {"name": "toy", "dim": 5}
    assert bundle.manifest["terrain_classes"] == ["grass"]
    assert bundle.manifest["components"]["map"]["points"] == 60
    back = load_map(Bundle(tmp_path / "m.terra"))
    np.testing.assert_array_equal(back.points, msm.points)
    np.testing.assert_array_equal(back.counts.toarray(), msm.counts.toarray())
    np.testing.assert_array_equal(back.terrain_votes, msm.terrain_votes)
    np.testing.assert_allclose(back.bank, msm.bank, atol=2e-3)  # float16 on disk
    queries = normalize_rows(rng.normal(size=(2, 5)))
    np.testing.assert_allclose(back.ms_avg_similarity(queries), msm.ms_avg_similarity(queries), atol=3e-3)
    assert not list(tmp_path.glob("m.terra/**/*.pkl"))


def test_embedder_is_recorded_and_a_mismatched_dimension_is_refused(tmp_path):
    from terra.errors import TerraError

    msm = random_map(np.random.default_rng(3))
    writer = BundleWriter(tmp_path / "m.terra")
    write_map(writer, msm)
    writer.set_embedder(msm.embedder, 4)  # the arrays hold 5-d rows
    bundle = writer.commit()
    with pytest.raises(
        TerraError, match=r"map/bank.npy: array of shape \(7, 5\), expected float16 \(7, 4\).*embedder's dimension"
    ):
        load_map(bundle)


@pytest.fixture(scope="module")
def box_map(tmp_path_factory, text_embedder):
    scene = BoxScene()
    run = run_mapping(scene, MappingConfig(), tmp_path_factory.mktemp("box") / "map.terra", show_progress=False)
    return scene, load_map(run.bundle)


def test_images_observing_matches_brute_force(box_map):
    scene, msm = box_map
    cell = msm.visibility.cell_size
    cam_pos = msm.images.position
    # Reference: for every image, the cells of the scan points it saw after the z-buffer.
    seen_cells = []
    for i in range(len(scene)):
        frame = scene[i]
        vis = visible_points(frame.points, scene.camera)
        pts = scene.points_map(i)[vis.index]
        seen_cells.append(np.unique(np.floor(pts / cell).astype(np.int64), axis=0))
    rng = np.random.default_rng(0)
    queries = np.concatenate([msm.points[rng.choice(len(msm), 150, replace=False)], [[500.0, 0.0, 0.0]]])
    lists, nearest = msm.images_observing(queries, max_range=12.0)
    q_cells = np.floor(queries / cell).astype(np.int64)
    for q in range(len(queries)):
        saw = [i for i in range(len(scene)) if (np.abs(seen_cells[i] - q_cells[q]).max(axis=1) <= 1).any()]
        dist = np.linalg.norm(cam_pos[saw] - queries[q], axis=1)
        assert lists[q].tolist() == [i for i, d in zip(saw, dist) if d <= 12.0]
        assert nearest[q] == (saw[int(np.argmin(dist))] if saw else -1)
    assert any(len(x) for x in lists) and nearest[-1] == -1
    # The camera pose of each image is the LiDAR pose composed with the extrinsics.
    np.testing.assert_allclose(
        msm.images.T_map_cam[2], scene.pose(2) @ np.linalg.inv(scene.camera.T_cam_lidar), atol=1e-9
    )


@pytest.mark.parametrize("bank_size", [12, 500])
def test_ms_avg_norms_equal_the_norms_of_the_dense_features(bank_size):
    """Row norms of counts @ bank: through the bank's Gram matrix when it has fewer entries than
    dimensions, directly otherwise; both against the dense product, row by row."""
    from terra.mapping.semantic_map import ms_avg_norms

    rng = np.random.default_rng(bank_size)
    bank = rng.normal(size=(bank_size, 64)).astype(np.float32)
    bank /= np.linalg.norm(bank, axis=1, keepdims=True)
    dense = np.where(rng.random((400, bank_size)) < 0.05, rng.integers(1, 300, (400, bank_size)), 0)
    dense[:50] = 0  # rows without observations
    expected = np.linalg.norm(dense.astype(np.float64) @ bank.astype(np.float64), axis=1)
    got = ms_avg_norms(sp.csr_matrix(dense.astype(np.int32)), bank)
    assert got.dtype == np.float32 and (got[:50] == 0).all()
    np.testing.assert_allclose(got, expected, rtol=1e-6)
