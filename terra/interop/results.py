"""What `terra import` and `terra export` return: typed summaries whose `to_json()` is the command's
`--json` output (`from_json` reads it back into an equal result). Text rendering lives in
terra/cli/render.py."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any


@dataclass
class ImportResult:
    """A bundle made from the reference's MS-map files: which save (`itr`) was read, the map's sizes,
    its terrain classes and embedder, how many image positions were recovered by each rule
    (recorded, the exact poses of Terra's export; else trilaterated, same_scan,
    centroid_of_seen_points, unknown), and notes for the user (what could not be checked)."""

    bundle: Path
    itr: int
    points: int
    observed_points: int
    bank: int
    images: int
    terrain_classes: list[str]
    embedder: str
    image_positions: dict[str, int]
    notes: list[str] = field(default_factory=list)
    format: str = "terra-reference"

    def to_json(self) -> dict[str, Any]:
        return {
            "format": self.format,
            "bundle": str(self.bundle),
            "itr": self.itr,
            "points": self.points,
            "bank": self.bank,
            "terrain_classes": list(self.terrain_classes),
            "embedder": self.embedder,
            "images": self.images,
            "image_positions": dict(self.image_positions),
            "observed_points": self.observed_points,
            "notes": list(self.notes),
        }

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> ImportResult:
        return cls(
            bundle=Path(data["bundle"]),
            itr=int(data["itr"]),
            points=int(data["points"]),
            observed_points=int(data["observed_points"]),
            bank=int(data["bank"]),
            images=int(data["images"]),
            terrain_classes=[str(c) for c in data["terrain_classes"]],
            embedder=str(data["embedder"]),
            image_positions={str(k): int(v) for k, v in data["image_positions"].items()},
            notes=[str(n) for n in data.get("notes", [])],
            format=str(data["format"]),
        )


@dataclass
class ExportResult:
    """An export: its format and output path, what it holds in the format's own terms (`details`,
    e.g. nodes and edges, or points and colour), and for some formats the files written or the
    layer ids."""

    format: str
    out: Path
    details: dict[str, int | str] = field(default_factory=dict)
    files: list[str] | None = None
    layers: dict[str, int] | None = None

    @classmethod
    def of(cls, summary: dict[str, Any]) -> ExportResult:
        """From an exporter's summary: format, out, the optional files and layers, and the rest."""
        details = {k: v for k, v in summary.items() if k not in ("format", "out", "files", "layers")}
        return cls(str(summary["format"]), Path(summary["out"]), details, summary.get("files"), summary.get("layers"))

    def to_json(self) -> dict[str, Any]:
        data: dict[str, Any] = {"format": self.format, "out": str(self.out), **self.details}
        if self.files is not None:
            data["files"] = list(self.files)
        if self.layers is not None:
            data["layers"] = dict(self.layers)
        return data

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> ExportResult:
        return cls.of(data)
