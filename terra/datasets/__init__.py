"""Data sources behind a registry: each loader module registers a name, a detector and an opener."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from terra.datasets.base import CameraFrame, ClassTable, Dataset, Frame, SemanticClass
from terra.errors import TerraError

__all__ = ["CameraFrame", "ClassTable", "Dataset", "Frame", "SemanticClass", "register_loader", "open_dataset", "loader_names"]


@dataclass(frozen=True)
class Loader:
    name: str
    detect: Callable[[Path], bool]
    open: Callable[[Path], Dataset]


_LOADERS: dict[str, Loader] = {}


def register_loader(name: str, detect: Callable[[Path], bool], open: Callable[[Path], Dataset]) -> None:
    """Register a data source format (called at import time by each loader module)."""
    _LOADERS[name] = Loader(name, detect, open)


def _ensure_builtin_loaders() -> None:
    # Imported lazily so `import terra.datasets` stays cheap and free of cycles.
    import terra.datasets.semantickitti  # noqa: F401
    import terra.datasets.terra_folder  # noqa: F401


def loader_names() -> list[str]:
    _ensure_builtin_loaders()
    return sorted(_LOADERS)


def open_dataset(path: str | Path, format: str = "auto") -> Dataset:
    """Open a dataset folder; `format` is a registered loader name or 'auto' to detect it."""
    _ensure_builtin_loaders()
    path = Path(path)
    if not path.exists():
        raise TerraError(f"{path}: dataset folder does not exist")
    if format != "auto":
        if format not in _LOADERS:
            raise TerraError(f"unknown dataset format {format!r}; expected one of: auto, {', '.join(sorted(_LOADERS))}")
        return _LOADERS[format].open(path)
    for loader in _LOADERS.values():
        if loader.detect(path):
            return loader.open(path)
    raise TerraError(f"{path}: not a recognised dataset (expected one of: {', '.join(sorted(_LOADERS))})")
