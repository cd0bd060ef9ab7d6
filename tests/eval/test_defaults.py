"""The shipped task defaults are what the demo's rule chooses on the demo's validation scene.

benchmarks/bench_defaults.py makes (or reuses) that scene exactly as `terra demo` does, tunes it
with `terra eval --tune`'s rule and records the result in benchmarks/results/defaults.json; here
the record must describe the demo's validation scene and give terra.tasks.config's defaults."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from terra.errors import TerraError
from terra.eval.demo import DemoConfig
from terra.eval.tuning import TunedParameters, defaults_from_tuned, shipped_defaults

RECORD = Path(__file__).resolve().parents[2] / "benchmarks" / "results" / "defaults.json"


def test_the_record_is_of_the_demos_validation_scene():
    record = json.loads(RECORD.read_text())
    demo = DemoConfig.load(None, "small", 0)
    scene = record["validation_scene"]
    assert (scene["preset"], scene["seed"], scene["frame_spacing_factor"]) == (
        demo.validation_preset,
        demo.validation_seed,
        demo.validation_spacing,
    )
    assert scene["noise"] == "realistic" and demo.mapping.perception.noise.enabled
    assert record["tuned"]["validation"]["dataset"] == f"sim-small-seed{demo.validation_seed}"


def test_the_shipped_defaults_are_the_tuned_values():
    record = json.loads(RECORD.read_text())
    tuned = TunedParameters.from_json(record["tuned"])
    chosen = defaults_from_tuned(tuned, DemoConfig().build.regions.method)
    assert chosen == shipped_defaults(tuned.embedder)
    # The rule reads the tuning itself: the default method's alpha, the default hierarchy's k.
    assert chosen["retrieval.alpha"] == tuned.retrieval["ms-avg"]["alpha"]
    assert chosen["monitoring.k"] == tuned.monitoring["agglomerative"]["k"]


def test_one_retrieval_default_needs_the_planners_method_to_agree():
    tuned = TunedParameters(
        "e",
        retrieval={"ms-avg": {"alpha": 0.65}, "3dsg": {"alpha": 0.5}},
        monitoring={"agglomerative": {"alpha": 0.35, "k": 5}, "aib": {"alpha": 0.5}},
    )
    with pytest.raises(TerraError, match="3dsg"):
        defaults_from_tuned(tuned)
