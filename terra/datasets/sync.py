"""Pairing streams by time stamp: each scan takes the nearest image, transform or pose of every
other stream, within a tolerance (seconds)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from terra.datasets.folder_io import stamp_of


def stamped_files(folder: Path, pattern: str) -> tuple[np.ndarray, list[Path]]:
    """Files of `folder` matching `pattern`, sorted by the stamp in their names (seconds)."""
    files = list(folder.glob(pattern)) if folder.is_dir() else []
    stamps = np.array([stamp_of(f) for f in files], float)
    order = np.argsort(stamps, kind="stable")
    return stamps[order], [files[i] for i in order]


def nearest(stamps: np.ndarray, t: float) -> tuple[int, float]:
    """Index of the stamp nearest `t` in sorted `stamps` (binary search) and its gap in seconds;
    (-1, inf) when there is none. Ties go to the earlier stamp."""
    if stamps.size == 0:
        return -1, np.inf
    i = int(np.searchsorted(stamps, t))
    candidates = [j for j in (i - 1, i) if 0 <= j < stamps.size]
    j = min(candidates, key=lambda k: abs(stamps[k] - t))
    return j, abs(float(stamps[j]) - t)
