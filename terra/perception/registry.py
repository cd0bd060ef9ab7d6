"""Perception backends by name (terra.registry): `labels` is built in; model backends (CLIP, YOLO,
FastSAM) register a factory with the same signature, here or through the `terra.perception`
entry-point group."""

from __future__ import annotations

from typing import Callable

from terra.datasets.base import ClassTable
from terra.perception.base import Perception
from terra.perception.config import PerceptionConfig
from terra.registry import Registry

BackendFactory = Callable[[PerceptionConfig, ClassTable], Perception]

BACKENDS: Registry[BackendFactory] = Registry(
    "perception.backend", "terra.perception", {"labels": "terra.perception.labels:labels_backend"}
)


def register_backend(name: str, factory: BackendFactory | str) -> None:
    """Make a perception backend available as `perception.backend: <name>`."""
    BACKENDS.register(name, factory)


def backend_names() -> list[str]:
    return BACKENDS.names()


def get_perception(config: PerceptionConfig, classes: ClassTable) -> Perception:
    """The configured backend for a source with class table `classes`."""
    return BACKENDS.get(config.backend)(config, classes)
