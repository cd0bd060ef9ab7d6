"""What `terra eval` returns: `EvalResult` (a report written), `TuneResult` (`--tune`) and
`TerrainTable` (`--terrain-only`, Table I) and `GroundTable` (`--ground-only`: LiDAR ground segmentation
against SemanticKITTI labels). `to_json()` is the command's `--json` output and
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


def _scores(tp: int, fp: int, fn: int) -> tuple[float, float, float]:
    """(precision, recall, F1); 0 where undefined (nothing found, nothing to find)."""
    return tp / max(tp + fp, 1), tp / max(tp + fn, 1), 2 * tp / max(2 * tp + fp + fn, 1)


@dataclass
class GroundScan:
    """One labelled scan: its points, those scored (not unlabeled or outlier), ground points found
    that are ground (tp), found that are not (fp), missed (fn), and the segmentation's seconds."""

    scan: str
    points: int
    scored: int
    tp: int
    fp: int
    fn: int
    seconds: float

    @property
    def precision(self) -> float:
        return _scores(self.tp, self.fp, self.fn)[0]

    @property
    def recall(self) -> float:
        return _scores(self.tp, self.fp, self.fn)[1]

    @property
    def f1(self) -> float:
        return _scores(self.tp, self.fp, self.fn)[2]

    def to_json(self) -> dict[str, Any]:
        return {
            "scan": self.scan,
            "points": self.points,
            "scored": self.scored,
            "tp": self.tp,
            "fp": self.fp,
            "fn": self.fn,
            "seconds": self.seconds,
            "precision": self.precision,
            "recall": self.recall,
            "f1": self.f1,
        }

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> GroundScan:
        points, scored, tp, fp, fn = (int(data[k]) for k in ("points", "scored", "tp", "fp", "fn"))
        return cls(str(data["scan"]), points, scored, tp, fp, fn, float(data["seconds"]))


@dataclass
class GroundTable:
    """`terra eval --ground-only`: `method` scored on the labelled scans of `sequence`, ground being
    the SemanticKITTI ids `ground_labels`; pooled scores over every scored point and the mean per
    scan; `timer` serves the text summary only."""

    sequence: str
    method: str
    ground_labels: list[int]
    scans: list[GroundScan]
    timer: StageTimer | None = field(default=None, compare=False, repr=False)

    def pooled(self) -> tuple[float, float, float]:
        """(precision, recall, F1) over the points of every scan together."""
        return _scores(*(sum(getattr(s, k) for s in self.scans) for k in ("tp", "fp", "fn")))

    def mean(self) -> tuple[float, float, float]:
        """(precision, recall, F1), each the mean over scans."""
        n = max(len(self.scans), 1)
        return (
            sum(s.precision for s in self.scans) / n,
            sum(s.recall for s in self.scans) / n,
            sum(s.f1 for s in self.scans) / n,
        )

    def to_json(self) -> dict[str, Any]:
        keys = ("precision", "recall", "f1")
        return {
            "sequence": self.sequence,
            "method": self.method,
            "ground_labels": list(self.ground_labels),
            "pooled": dict(zip(keys, self.pooled())),
            "mean_per_scan": dict(zip(keys, self.mean())),
            "scans": [s.to_json() for s in self.scans],
        }

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> GroundTable:
        scans = [GroundScan.from_json(s) for s in data["scans"]]
        return cls(str(data["sequence"]), str(data["method"]), [int(i) for i in data["ground_labels"]], scans)
