"""End to end on the simulated campus (noise-free labels): object classes, terrain and image
visibility against the simulator's ground truth. (Resumption after a killed process:
tests/mapping/test_mapping_cli.py.)"""

import numpy as np
import pytest

from terra.mapping.storage import load_map

pytestmark = pytest.mark.slow


def check_against_ground_truth(mapped, dataset, text_embedder):
    """The issue's acceptance on a noise-free map: >= 95% of observed object points have their own
    class as MS-Max, and the terrain vote agrees with the ground-truth terrain for >= 95% of the
    voted points (against the simulator's terrain raster and against the points' own labels)."""
    bundle = mapped.bundle
    noise = bundle.manifest["components"]["map"]["config"]["perception"]["noise"]
    assert noise["dilate_px"] == 0 and noise["miss_rate"] == 0 and noise["confusion_rate"] == 0
    msm = load_map(bundle)
    truth = mapped.truth.point_truth()
    assert truth.shape[0] == len(msm)
    classes = dataset.classes
    named = [c for c in classes if c.id != 0]
    ids = np.array([c.id for c in named])
    entry_class = ids[(msm.bank @ text_embedder.embed_text([c.name for c in named]).T).argmax(axis=1)]
    best = msm.ms_max_ids()
    object_ids = [c.id for c in named if not c.terrain]
    observed_objects = (best >= 0) & np.isin(truth, object_ids)
    assert observed_objects.sum() > 1000
    accuracy = np.mean(entry_class[best[observed_objects]] == truth[observed_objects])
    assert accuracy >= 0.95, accuracy
    terrain_ids = np.array([c.id for c in classes.terrain_classes])
    t = msm.terrain_index()
    voted = t >= 0
    assert voted.sum() > 1000
    raster = dataset.ground_truth().terrain.class_at(msm.points[:, :2])
    covered = voted & (raster >= 0)
    assert covered.sum() > 1000
    assert np.mean(terrain_ids[t[covered]] == raster[covered]) >= 0.95
    assert np.mean(terrain_ids[t[voted]] == truth[voted]) >= 0.95
    return msm


def test_tiny_campus_map_matches_ground_truth(tiny_campus, tiny_mapped, text_embedder):
    msm = check_against_ground_truth(tiny_mapped, tiny_campus, text_embedder)
    n_cameras = len(tiny_campus[0].cameras)
    assert len(msm.images) == len(tiny_campus) * n_cameras
    # Query, per image, the visible scan point nearest to its camera (a few metres ahead: the
    # cameras look forward and down). That image saw the spot from well within 20 m, so it must be
    # listed; every listed camera is within 20 m; the nearest observer is no farther than it.
    # (Images are stored in (frame, camera) order; none was skipped, so image j is the j-th key.)
    recorded = tiny_mapped.truth.nearest_seen
    queries = np.array([recorded[key] for key in sorted(recorded)])
    own = np.arange(len(queries))
    lists, nearest = msm.images_observing(queries, max_range=20.0)
    cameras = msm.images.position
    assert all(j in listed for j, listed in zip(own, lists))
    for q, listed in zip(queries, lists):
        assert np.all(np.linalg.norm(cameras[listed] - q, axis=1) <= 20.0)
    assert np.all(nearest >= 0)
    assert np.all(np.linalg.norm(cameras[nearest] - queries, axis=1) <= np.linalg.norm(cameras[own] - queries, axis=1))


def test_small_campus_map_matches_ground_truth(small_campus, small_mapped, text_embedder):
    check_against_ground_truth(small_mapped, small_campus, text_embedder)
