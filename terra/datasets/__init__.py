"""Data sources behind one registry (`terra.datasets.registry.LOADERS`): each loader module
exposes a `LOADER` with a name, a detector, an opener and its options section."""

from __future__ import annotations

from terra.datasets.base import CameraFrame, ClassTable, Dataset, Frame, SemanticClass
from terra.datasets.registry import LOADERS, Loader, loader_names, open_dataset

__all__ = [
    "CameraFrame",
    "ClassTable",
    "Dataset",
    "Frame",
    "SemanticClass",
    "LOADERS",
    "Loader",
    "loader_names",
    "open_dataset",
]
