"""Perception: protocols and backends that turn images and text into masks and unit embeddings.

`get_perception(config, classes)` returns the configured backend (`labels` by default).
"""

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
