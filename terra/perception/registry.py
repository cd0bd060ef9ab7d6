"""Perception backends by name. `labels` is built in; model backends (CLIP, YOLO, FastSAM)
register a factory here with the same signature."""

from __future__ import annotations

from typing import Callable

from terra.datasets.base import ClassTable
from terra.errors import TerraError
from terra.perception.base import Perception
from terra.perception.config import PerceptionConfig

BackendFactory = Callable[[PerceptionConfig, ClassTable], Perception]


def _labels(config: PerceptionConfig, classes: ClassTable) -> Perception:
    from terra.perception.labels import labels_backend

    return labels_backend(config, classes)


_BACKENDS: dict[str, BackendFactory] = {"labels": _labels}


def register_backend(name: str, factory: BackendFactory) -> None:
    """Make a perception backend available as `perception.backend: <name>`."""
    _BACKENDS[name] = factory


def backend_names() -> list[str]:
    return sorted(_BACKENDS)


def get_perception(config: PerceptionConfig, classes: ClassTable) -> Perception:
    """The configured backend for a source with class table `classes`."""
    if config.backend not in _BACKENDS:
        raise TerraError(f"perception.backend {config.backend!r} is unknown; expected one of: {', '.join(backend_names())}")
    return _BACKENDS[config.backend](config, classes)
