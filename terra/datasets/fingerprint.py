"""A dataset recognised by what it holds, not by where it lives: a copied or renamed dataset has
the fingerprint of the original, another drive (another seed, another sequence) does not.

The fingerprint is the SHA-256 of the frame count, the class table and, for a few frames spread
over the drive (the first, the middle and the last by default), the scan's stamp and its points
as float32 metres in the sensor frame. Poses are left out on purpose: a map made with odometry
poses comes from the same data as one made with the source's own. Reading three frames costs
well under a second on any loader, so `terra map` records it and `terra eval` checks it.
"""

from __future__ import annotations

import hashlib
import json

import numpy as np

from terra.datasets.base import Dataset


def raw_source(dataset: Dataset) -> Dataset:
    """The dataset under wrappers that change poses or points (odometry), whose frames are the
    source's own."""
    while True:
        source = getattr(dataset, "source", None)
        if source is None or not hasattr(source, "__getitem__"):
            return dataset
        dataset = source


def sample_frames(count: int, samples: int = 3) -> list[int]:
    """Indices of `samples` frames spread evenly from the first to the last (fewer for short drives)."""
    if count <= 0:
        return []
    return sorted({int(round(i)) for i in np.linspace(0, count - 1, min(samples, count))})


def dataset_fingerprint(dataset: Dataset, samples: int = 3) -> str:
    """Hex SHA-256 of what `dataset` holds (see the module docstring); independent of its path and name."""
    source = raw_source(dataset)
    digest = hashlib.sha256()
    classes = source.classes.to_json() if hasattr(source.classes, "to_json") else []
    digest.update(json.dumps({"frames": len(source), "classes": classes}, sort_keys=True).encode())
    for index in sample_frames(len(source), samples):
        digest.update(_frame_bytes(source, index))
    return digest.hexdigest()


def _frame_bytes(source: Dataset, index: int) -> bytes:
    """A frame's stamp and points; a frame the loader cannot read (mapping skips it and counts
    it) contributes the fact that it is unreadable, which is also what it holds."""
    from terra.errors import TerraError

    try:
        frame = source[index]
        points = np.asarray(frame.points, dtype=np.float32)
        xyz = points[:, :3] if points.ndim == 2 and points.shape[1] >= 3 else points.reshape(-1)
        points = np.ascontiguousarray(xyz)
    except TerraError:
        return f"{index}:unreadable".encode()
    return f"{index}:{float(frame.stamp):.6f}:{points.shape}".encode() + points.tobytes()
