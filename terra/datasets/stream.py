"""Frames over time: the `FrameSource` protocol beside the random-access `Dataset`.

A `Dataset` is a recording that is complete when it is opened (`len`, `dataset[i]`). A
`FrameSource` is what arrives while a robot drives: an iterator of `Frame`s in time order that
may wait for more and may never end (a bag still being recorded, frames pushed by a program). The
incremental mapper (terra.mapping.mapper.Mapper, behind terra.live.Session) consumes either; every
Dataset is a FrameSource through `DatasetSource`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Protocol, runtime_checkable

from terra.datasets.base import ClassTable, Dataset, Frame
from terra.errors import TerraError

__all__ = ["DatasetSource", "FrameSource", "WaitingSource", "as_source"]


@runtime_checkable
class FrameSource(Protocol):
    """Frames in time order (stamps increasing), possibly waiting between them, possibly endless.

    name: the source's name (a recording's stem). classes: its label vocabulary. `frames()` is
    called once; closing the iterator early (an error, Ctrl-C) releases what the source holds."""

    name: str
    classes: ClassTable

    def frames(self) -> Iterator[Frame]: ...


@runtime_checkable
class WaitingSource(FrameSource, Protocol):
    """A source that waits for frames (a recording that grows) calls `on_wait` at each wait, so
    its consumer can commit what it has or report the stall meanwhile; `waiting_for()`: seconds
    since the source last received anything."""

    on_wait: Callable[[], None] | None

    def waiting_for(self) -> float: ...


class DatasetSource:
    """Every frame of a random-access `dataset`, from frame `start` on, in index order (a dataset's
    frames are in time order). A frame that cannot be read raises its TerraError."""

    def __init__(self, dataset: Dataset, start: int = 0) -> None:
        if start < 0:
            raise TerraError(f"{dataset.name}: start frame must be >= 0, got {start}")
        self.dataset = dataset
        self.name = dataset.name
        self.classes = dataset.classes
        self.start = start

    def frames(self) -> Iterator[Frame]:
        for i in range(self.start, len(self.dataset)):
            yield self.dataset[i]


def as_source(source: Dataset | FrameSource) -> FrameSource:
    """`source` itself when it is a FrameSource, else its frames in index order."""
    if isinstance(source, FrameSource):
        return source
    return DatasetSource(source)
