"""Perception: protocols and backends that turn images and text into masks and unit embeddings.

`get_perception(config, classes)` returns the configured backend (`labels` by default).

The names below load on first use (PEP 562): a query command imports terra.perception.text only,
and must not pay for the image side (datasets, geometry, SciPy's image module) to do so.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from terra.perception.base import (
        ImageEmbedder,
        ImagePerception,
        MaskEmbedder,
        MaskProposer,
        Perception,
        PointPerception,
        TerrainSegmenter,
    )
    from terra.perception.masks import MaskSet
    from terra.perception.registry import backend_names, get_perception, register_backend

_EXPORTS = {
    "ImageEmbedder": "terra.perception.base",
    "ImagePerception": "terra.perception.base",
    "MaskEmbedder": "terra.perception.base",
    "MaskProposer": "terra.perception.base",
    "Perception": "terra.perception.base",
    "PointPerception": "terra.perception.base",
    "TerrainSegmenter": "terra.perception.base",
    "MaskSet": "terra.perception.masks",
    "backend_names": "terra.perception.registry",
    "get_perception": "terra.perception.registry",
    "register_backend": "terra.perception.registry",
}

__all__ = [
    "ImageEmbedder",
    "ImagePerception",
    "MaskEmbedder",
    "MaskProposer",
    "MaskSet",
    "Perception",
    "PointPerception",
    "TerrainSegmenter",
    "backend_names",
    "get_perception",
    "register_backend",
]


def __getattr__(name: str) -> Any:
    if name not in _EXPORTS:
        raise AttributeError(f"module 'terra.perception' has no attribute {name!r}")
    value = getattr(importlib.import_module(_EXPORTS[name]), name)
    globals()[name] = value
    return value
