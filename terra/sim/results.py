"""What `terra sim` returns: `SimResult`, whose `to_json()` is its `--json` output (`from_json` reads
it back into an equal result). Text rendering lives in terra/cli/render.py."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from terra.progress import StageTimer


@dataclass
class SimResult:
    """A simulated dataset written: its folder and format, frames, ground-truth objects and named
    regions, the picture beside it, and stage timings (`timer`, calls per stage, for the text
    table only: not in the JSON, not compared)."""

    folder: Path
    format: str
    name: str
    frames: int
    objects: int
    regions: int
    picture: str
    seconds: dict[str, float]
    timer: StageTimer | None = field(default=None, compare=False, repr=False)

    def to_json(self) -> dict[str, Any]:
        return {
            "folder": str(self.folder),
            "format": self.format,
            "name": self.name,
            "frames": self.frames,
            "objects": self.objects,
            "regions": self.regions,
            "picture": self.picture,
            "seconds": dict(self.seconds),
        }

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> SimResult:
        return cls(
            folder=Path(data["folder"]),
            format=str(data["format"]),
            name=str(data["name"]),
            frames=int(data["frames"]),
            objects=int(data["objects"]),
            regions=int(data["regions"]),
            picture=str(data["picture"]),
            seconds={str(k): float(v) for k, v in data["seconds"].items()},
        )
