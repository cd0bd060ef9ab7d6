"""Perception backends by name (terra.registry): `labels` (the dataset's own labels) and `models`
(YOLO terrain, FastSAM, CLIP weight files; terra/perception/models.py) are built in; other backends
register a factory with the same signature, here or through the `terra.perception` entry-point group."""

from __future__ import annotations

from collections.abc import Callable

from terra.datasets.base import ClassTable
from terra.perception.base import Perception, TerrainSegmenter
from terra.perception.config import PerceptionConfig
from terra.registry import Registry

BackendFactory = Callable[[PerceptionConfig, ClassTable], Perception]

BACKENDS: Registry[BackendFactory] = Registry(
    "perception.backend",
    "terra.perception",
    {"labels": "terra.perception.labels:labels_backend", "models": "terra.perception.models:models_backend"},
)


def register_backend(name: str, factory: BackendFactory | str) -> None:
    """Make a perception backend available as `perception.backend: <name>`."""
    BACKENDS.register(name, factory)


def backend_names() -> list[str]:
    return BACKENDS.names()


def get_perception(config: PerceptionConfig, classes: ClassTable) -> Perception:
    """The configured backend for a source with class table `classes`."""
    return BACKENDS.get(config.backend)(config, classes)


def get_terrain_segmenter(config: PerceptionConfig, classes: ClassTable) -> TerrainSegmenter:
    """Only the configured backend's terrain segmenter: a factory may offer it as its `terrain_segmenter`
    attribute (so terrain evaluation loads no other model); otherwise the whole backend is built."""
    factory = BACKENDS.get(config.backend)
    only_terrain = getattr(factory, "terrain_segmenter", None)
    return only_terrain(config, classes) if only_terrain is not None else factory(config, classes).terrain
