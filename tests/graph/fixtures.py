"""Session fixtures of the graph stage (see tests/conftest.py).

`tiny_graph_bundle` / `small_graph_bundle`: a copy of the mapping fixtures' tiny / small map bundle
in a fresh folder, with the scene graph built by the default BuildConfig (agglomerative regions).
They are built once per session; tests must not modify them (copy them first, e.g. with
`copy_bundle`).
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import cast

import numpy as np
import pytest
from scipy import ndimage

from terra.bundle import Bundle


def copy_bundle(bundle: Bundle | Path, dest: Path) -> Path:
    """Copy a bundle folder to `dest` (which must not exist) and return `dest`."""
    src = bundle.path if isinstance(bundle, Bundle) else Path(bundle)
    shutil.copytree(src, dest)
    return dest


def label_parts(mask: np.ndarray, structure: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """ndimage.label(mask, structure): (labels, count). scipy's function is untyped, and its
    caller-provided-output branch (a bare count) makes every call read as possibly an int."""
    return cast(tuple[np.ndarray, int], ndimage.label(mask, structure=structure))


def _graph_bundle(map_bundle: Bundle, tmp_path_factory, name: str) -> Bundle:
    from terra.graph.pipeline import build_graph

    path = copy_bundle(map_bundle, tmp_path_factory.mktemp(name) / "graph.terra")
    build_graph(path, progress=False)
    return Bundle(path)


@pytest.fixture(scope="session")
def tiny_graph_bundle(tiny_bundle, tmp_path_factory) -> Bundle:
    """Bundle with the map of simulate('tiny', 0) and its scene graph (default build config)."""
    return _graph_bundle(tiny_bundle, tmp_path_factory, "tiny_graph_bundle")


@pytest.fixture(scope="session")
def small_graph_bundle(small_bundle, tmp_path_factory) -> Bundle:
    """Bundle with the map of simulate('small', 0) and its scene graph (default build config)."""
    return _graph_bundle(small_bundle, tmp_path_factory, "small_graph_bundle")
