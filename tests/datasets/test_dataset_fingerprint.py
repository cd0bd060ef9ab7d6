"""A dataset is recognised by what it holds: a copied or renamed SemanticKITTI sequence has the
fingerprint the map recorded, a changed scan or another drive does not."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest

from terra.bundle import Bundle
from terra.datasets import open_dataset
from terra.datasets.fingerprint import dataset_fingerprint, sample_frames
from terra.errors import TerraError
from terra.eval.inputs import check_same_dataset, mapped_dataset_fingerprint
from terra.sim.writer import write_dataset
from tests.datasets.fixtures import HandDataset


@pytest.fixture(scope="module")
def mapped_sequence(tmp_path_factory, text_embedder):
    """A SemanticKITTI sequence written from the hand dataset, and its map."""
    from terra.mapping.config import MappingConfig
    from terra.mapping.pipeline import build_map

    root = tmp_path_factory.mktemp("fingerprint")
    sequence = write_dataset(HandDataset(), root / "kitti", format="semantickitti", progress=False)
    bundle = build_map(open_dataset(sequence), MappingConfig(), root / "seq00.terra", progress=False)
    return sequence, bundle


def test_samples_spread_over_the_drive():
    assert sample_frames(0) == [] and sample_frames(1) == [0] and sample_frames(2) == [0, 1]
    assert sample_frames(101) == [0, 50, 100]


def test_the_map_records_the_fingerprint_of_its_dataset(mapped_sequence):
    sequence, bundle = mapped_sequence
    recorded = Bundle(bundle.path).manifest["components"]["map"]["dataset"]
    assert recorded == {
        "name": open_dataset(sequence).name,
        "fingerprint": dataset_fingerprint(open_dataset(sequence)),
        "frames": len(HandDataset()),
    }
    assert mapped_dataset_fingerprint(Bundle(bundle.path)) == recorded["fingerprint"]


def test_a_renamed_copy_is_the_same_dataset(mapped_sequence, tmp_path):
    sequence, bundle = mapped_sequence
    copy = Path(shutil.copytree(sequence, tmp_path / "drive_a"))
    renamed = open_dataset(copy)
    assert renamed.name != open_dataset(sequence).name  # SemanticKITTI names a sequence by its folders
    assert check_same_dataset(Bundle(bundle.path), renamed, copy) == mapped_dataset_fingerprint(Bundle(bundle.path))


def test_a_changed_scan_is_another_dataset(mapped_sequence, tmp_path):
    sequence, bundle = mapped_sequence
    copy = Path(shutil.copytree(sequence, tmp_path / "kitti"))  # even under the same name
    scan = sorted(copy.glob("sequences/*/velodyne/*.bin"))[-1]  # the last frame is always sampled
    data = np.fromfile(scan, dtype=np.float32)
    data[0] += 1.0
    data.tofile(scan)
    assert open_dataset(copy).name == open_dataset(sequence).name
    with pytest.raises(TerraError, match="not the dataset .* was mapped from"):
        check_same_dataset(Bundle(bundle.path), open_dataset(copy), copy)


def test_odometry_poses_do_not_change_the_fingerprint(mapped_sequence):
    """A map made with KISS-ICP poses comes from the same data: the fingerprint reads the source."""
    from terra.datasets.fingerprint import raw_source

    sequence, _ = mapped_sequence
    source = open_dataset(sequence)

    class Wrapped:  # like terra.odometry.kiss.OdometryDataset: other poses, same frames underneath
        def __init__(self, inner):
            self.source, self.name, self.classes = inner, inner.name, inner.classes

        def __len__(self):
            return len(self.source)

        def __getitem__(self, index):
            frame = self.source[index]
            frame.T_map_lidar = np.eye(4)
            return frame

        def global_map(self):
            return None

    assert raw_source(Wrapped(source)) is source
    assert dataset_fingerprint(Wrapped(source)) == dataset_fingerprint(source)
