"""What `terra eval` returns: `EvalResult` (a report written), `TuneResult` (`--tune`) and
`TerrainTable` (`--terrain-only`, Table I). `to_json()` is the command's `--json` output and
`from_json` reads it back into an equal result; text rendering lives in terra/cli/render.py.

The report's sections (segmentation, retrieval, regions, memory, places, navigation, figures) stay
the JSON documents of summary.json that terra/eval/report.py writes into report.md: `EvalResult`
types what the command itself reads (what was evaluated, where the parameters came from, where the
report is) and carries the sections as they are written."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from terra.eval.tuning import TunedParameters
    from terra.progress import StageTimer

JsonDocument = dict[str, Any]  # a section of summary.json, as written


@dataclass
class EvalResult:
    """A report written to `report` (a folder: report.md, summary.json, figures/): the bundle and
    dataset names, the embedder, where alpha and k came from (`parameters`, its `source` in words),
    and the report's sections (`sections`: every other key of summary.json). `bundle`, `gt`,
    `report` (the paths given) and `timer` serve the text summary only: not in the JSON, not
    compared."""

    bundle_name: str
    dataset: str
    embedder: str
    parameters: JsonDocument
    sections: JsonDocument
    bundle: Path | None = field(default=None, compare=False)
    gt: Path | None = field(default=None, compare=False)
    report: Path | None = field(default=None, compare=False)
    timer: StageTimer | None = field(default=None, compare=False, repr=False)

    @property
    def parameter_source(self) -> str:
        return str(self.parameters.get("source", ""))

    def summary(self) -> JsonDocument:
        """summary.json as written (the report's headline reads it)."""
        return self.to_json()

    def to_json(self) -> dict[str, Any]:
        return {
            "bundle": self.bundle_name,
            "dataset": self.dataset,
            "embedder": self.embedder,
            "parameters": self.parameters,
            **self.sections,
        }

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> EvalResult:
        head = ("bundle", "dataset", "embedder", "parameters")
        return cls(
            bundle_name=str(data["bundle"]),
            dataset=str(data["dataset"]),
            embedder=str(data["embedder"]),
            parameters=dict(data["parameters"]),
            sections={k: v for k, v in data.items() if k not in head},
        )


@dataclass
class TuneResult:
    """`terra eval --tune`: the parameters chosen (TunedParameters, whose JSON is tuned.json) and
    where they were written; `bundle`, `gt`, `path` and `timer` serve the text summary only."""

    params: TunedParameters
    path: Path | None = field(default=None, compare=False)
    bundle: Path | None = field(default=None, compare=False)
    gt: Path | None = field(default=None, compare=False)
    timer: StageTimer | None = field(default=None, compare=False, repr=False)

    def to_json(self) -> dict[str, Any]:
        return self.params.to_json()

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> TuneResult:
        from terra.eval.tuning import TunedParameters

        return cls(TunedParameters.from_json(data))


@dataclass
class TerrainRow:
    """Table I figures of one segmenter: per-class IoU and F1 (None: the class is absent), mIoU,
    frequency-weighted mIoU, F1, frames per second (None for a label lookup), images scored."""

    classes: list[str]
    iou: list[float | None]
    f1_per_class: list[float | None]
    miou: float
    fw_miou: float
    f1: float
    fps: float | None
    images: int

    def to_json(self) -> dict[str, Any]:
        return {
            "classes": list(self.classes),
            "iou": list(self.iou),
            "f1_per_class": list(self.f1_per_class),
            "miou": self.miou,
            "fw_miou": self.fw_miou,
            "f1": self.f1,
            "fps": self.fps,
            "images": self.images,
        }

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> TerrainRow:
        optional = lambda values: [None if v is None else float(v) for v in values]  # noqa: E731
        return cls(
            classes=[str(c) for c in data["classes"]],
            iou=optional(data["iou"]),
            f1_per_class=optional(data["f1_per_class"]),
            miou=float(data["miou"]),
            fw_miou=float(data["fw_miou"]),
            f1=float(data["f1"]),
            fps=None if data["fps"] is None else float(data["fps"]),
            images=int(data["images"]),
        )


@dataclass
class TerrainTable:
    """`terra eval --terrain-only`: Table I of each segmenter (a row per label) on the same
    labelled images of `dataset`; `timer` serves the text summary only."""

    dataset: str
    images: int
    methods: dict[str, TerrainRow]
    timer: StageTimer | None = field(default=None, compare=False, repr=False)

    def to_json(self) -> dict[str, Any]:
        return {
            "dataset": self.dataset,
            "images": self.images,
            "methods": {name: row.to_json() for name, row in self.methods.items()},
        }

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> TerrainTable:
        methods = {str(name): TerrainRow.from_json(row) for name, row in data["methods"].items()}
        return cls(str(data["dataset"]), int(data["images"]), methods)
