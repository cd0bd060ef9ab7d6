"""Parameters chosen on a validation scene and applied unchanged to the test scene.

`terra eval --tune` grid-searches, on a validation bundle (another simulator seed) and its ground
truth: alpha per retrieval method (best Table II F1), and per monitoring method (best Table III
F1) alpha (AIB's null-task score for "aib") with, for Terra's hierarchies, k and the number of
region levels ranked (from level 1 or 2 up to a cap). Ties keep the first grid point: from level 1
before from level 2, all levels before a level cap, smallest k, smallest alpha. The result is a
small JSON file (`tuned.json`) that `terra eval --tuned FILE` reads; the test labels are never
looked at while choosing.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from terra.bundle import atomic_write_bytes, dumps_json
from terra.errors import TerraError
from terra.eval.config import TuneEval

TUNED_SCHEMA = "terra-tuned-parameters"
TUNED = "tuned.json"  # file name written by `terra eval --tune`


@dataclass
class TunedParameters:
    """alpha per retrieval method; {alpha, k, levels, min_level, query} per monitoring method (query:
    the tasks.monitoring.query they were tuned with); `validation`: the dataset and bundle they
    were chosen on."""

    embedder: str
    retrieval: dict[str, dict] = field(default_factory=dict)
    monitoring: dict[str, dict] = field(default_factory=dict)
    validation: dict[str, str] = field(default_factory=dict)

    def retrieval_alpha(self, method: str) -> float | None:
        return self.retrieval.get(method, {}).get("alpha")

    def monitoring_params(self, method: str) -> tuple[float | None, int | None]:
        entry = self.monitoring.get(method, {})
        return entry.get("alpha"), entry.get("k")

    def monitoring_levels(self, method: str) -> int | None:
        """Region levels ranked by `method` (None = all)."""
        return self.monitoring.get(method, {}).get("levels")

    def monitoring_min_level(self, method: str) -> int | None:
        """Lowest region level ranked by `method` (None = level 1)."""
        return self.monitoring.get(method, {}).get("min_level")

    def to_json(self) -> dict:
        return {
            "schema": TUNED_SCHEMA,
            "embedder": self.embedder,
            "retrieval": self.retrieval,
            "monitoring": self.monitoring,
            "validation": self.validation,
        }

    def save(self, path: str | Path) -> Path:
        path = Path(path)
        atomic_write_bytes(path, dumps_json(self.to_json()).encode())
        return path

    @classmethod
    def load(cls, path: str | Path) -> TunedParameters:
        path = Path(path)
        try:
            data = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            raise TerraError(f"{path}: cannot read tuned parameters ({exc})") from None
        if not isinstance(data, dict) or data.get("schema") != TUNED_SCHEMA:
            raise TerraError(f"{path}: field 'schema' is not {TUNED_SCHEMA!r}; write one with `terra eval --tune`")
        try:
            return cls.from_json(data)
        except (KeyError, TypeError, ValueError) as exc:
            raise TerraError(f"{path}: malformed tuned parameters ({exc})") from None

    @classmethod
    def from_json(cls, data: dict) -> TunedParameters:
        """The parameters of tuned.json's document (KeyError, TypeError or ValueError when malformed)."""
        return cls(
            str(data["embedder"]),
            dict(data.get("retrieval", {})),
            dict(data.get("monitoring", {})),
            dict(data.get("validation", {})),
        )

    @property
    def validation_dataset(self) -> str:
        """Name of the dataset the parameters were chosen on ("" when not recorded)."""
        return str(self.validation.get("dataset", ""))

    def check_not_tuned_on(self, test_dataset: str, source: str = "tuned parameters", fingerprint: str = "") -> None:
        """TerraError unless the parameters record a validation scene other than `test_dataset`:
        alpha and k must never be chosen on the labels they are scored against. The scenes are
        compared by content (`fingerprint`, terra.datasets.fingerprint) when both are recorded,
        so a renamed copy of the validation scene is still recognised; else by name."""
        if not self.validation_dataset:
            raise TerraError(f"{source}: field 'validation.dataset' is missing; tune again with `terra eval --tune`")
        recorded = str(self.validation.get("fingerprint") or "")
        if recorded and fingerprint:
            if recorded == fingerprint:
                raise TerraError(
                    f"{source} were tuned on the scene under test ({self.validation_dataset!r}, the same "
                    "frames); tune on a validation scene (another seed) instead"
                )
            return
        if self.validation_dataset == test_dataset:
            raise TerraError(
                f"{source} were tuned on {test_dataset!r}, the scene under test; "
                "tune on a validation scene (another seed) instead"
            )

    def check_query_mode(self, mode: str, source: str = "tuned parameters") -> None:
        """TerraError when a monitoring method was tuned with another `tasks.monitoring.query` than
        `mode` (its alpha belongs to that query embedding); files without the record pass."""
        for method, entry in sorted(self.monitoring.items()):
            recorded = entry.get("query") if isinstance(entry, dict) else None
            if recorded is not None and recorded != mode:
                raise TerraError(
                    f"{source}: {method} monitoring was tuned with tasks.monitoring.query {recorded!r} "
                    f"but the configuration has {mode!r}; tune again or set it to {recorded!r}"
                )

    def check_embedder(self, embedder: str, source: str = "tuned parameters") -> None:
        if self.embedder != embedder:
            raise TerraError(
                f"{source} were tuned for embedder {self.embedder!r} but the map uses {embedder!r}; tune again"
            )


def alpha_grid(config: TuneEval) -> list[float]:
    """The alphas searched, rounded to 4 decimals so the file reads cleanly."""
    return [round(float(a), 4) for a in np.linspace(config.alpha_min, config.alpha_max, config.alpha_steps)]


def best_point(points: list[dict], key: str = "f1") -> dict:
    """The first grid point with the highest `key` (grid order breaks ties)."""
    return points[int(np.argmax([p[key] for p in points]))] if points else {}


# ---------------------------------------------------------------- the shipped defaults


def defaults_from_tuned(tuned: TunedParameters, region_method: str = "agglomerative") -> dict[str, float | int]:
    """The task defaults a tuning gives, by the rule Terra's shipped defaults follow
    (benchmarks/bench_defaults.py runs it on the demo's validation scene): retrieval's one alpha
    per embedder is the one tuned for the default method (tasks.retrieval.method, MS-Avg), which
    must also be the planner's method's (3dsg); monitoring's alpha, k and lowest level those tuned
    for the default hierarchy (`region_method`, build.regions.method); AIB's null-task score the
    one tuned for "aib"."""
    from terra.tasks.config import PlanningConfig, RetrievalConfig

    method, planner = RetrievalConfig().method, PlanningConfig().find_method
    alpha = tuned.retrieval_alpha(method)
    if alpha is None or tuned.retrieval_alpha(planner) != alpha:
        raise TerraError(
            f"tuned retrieval alphas differ between {method} ({alpha}) and {planner} "
            f"({tuned.retrieval_alpha(planner)}): one default cannot serve both"
        )
    monitoring = tuned.monitoring.get(region_method, {})
    return {
        "retrieval.alpha": float(alpha),
        "monitoring.alpha": float(monitoring["alpha"]),
        "monitoring.k": int(monitoring["k"]),
        "monitoring.min_level": int(monitoring.get("min_level") or 1),
        "monitoring.aib.null_score": float(tuned.monitoring["aib"]["alpha"]),
    }


def shipped_defaults(embedder: str) -> dict[str, float | int]:
    """The same values as the configuration ships them for `embedder` (terra.tasks.config)."""
    from terra.tasks.config import TasksConfig, alpha_for

    tasks = TasksConfig()
    r, m = tasks.retrieval, tasks.monitoring
    return {
        "retrieval.alpha": alpha_for(r.alpha, r.default_alpha, embedder),
        "monitoring.alpha": alpha_for(m.alpha, m.default_alpha, embedder),
        "monitoring.k": m.k,
        "monitoring.min_level": m.min_level,
        "monitoring.aib.null_score": alpha_for(m.aib.null_score, m.aib.default_null_score, embedder),
    }
