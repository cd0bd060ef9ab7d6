"""End to end on the simulated campus (noise-free labels): object classes and terrain against the
simulator's ground truth, and resumption on the tiny preset."""

import hashlib
from pathlib import Path

import numpy as np
import pytest

from terra.mapping.config import MappingConfig
from terra.mapping.pipeline import run_mapping
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


class Killed(Exception):
    pass


class KilledAfter:
    """Wraps a dataset; loading frame `at` raises (as a killed process would stop there)."""

    def __init__(self, dataset, at: int):
        self._dataset, self._at = dataset, at
        self.name, self.classes = dataset.name, dataset.classes

    def __len__(self):
        return len(self._dataset)

    def __getitem__(self, i):
        if i == self._at:
            raise Killed(i)
        return self._dataset[i]

    def global_map(self):
        return self._dataset.global_map()


def digest(path: Path) -> dict[str, str]:
    return {str(p.relative_to(path)): hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(path.rglob("*")) if p.is_file()}


def test_tiny_resume_equals_uninterrupted(tiny_campus, tiny_bundle, tmp_path):
    config = MappingConfig(checkpoint_every=8)
    assert config.model_dump(exclude={"checkpoint_every"}) == MappingConfig().model_dump(exclude={"checkpoint_every"})
    out = tmp_path / "map.terra"
    with pytest.raises(Killed):
        run_mapping(KilledAfter(tiny_campus, 19), config, out, show_progress=False)
    run = run_mapping(tiny_campus, config, out, show_progress=False)
    assert run.resumed_from == 16
    uninterrupted = digest(tiny_bundle.path)
    resumed = digest(out)
    # Only the recorded config (checkpoint_every) may differ: every array is byte-identical.
    differing = {k for k in uninterrupted if uninterrupted[k] != resumed.get(k)}
    assert differing <= {"manifest.json"}
    assert set(uninterrupted) == set(resumed)
