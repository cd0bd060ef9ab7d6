"""The evaluation runner and `terra eval` on the tiny demo's scenes (session fixture `tiny_demo`):
report contents checked against independently computed values, tuning provenance, bad input."""

import json
import os
from typing import Any

import numpy as np
import pytest
from matplotlib.path import Path as MplPath
from PIL import Image

from tests.eval.fixtures import run_cli

FAST = "eval:\n  figures: false\n  segmentation:\n    max_images: 0\n"
MEASURED = {"runtime_ms", "regions_ms", "query_ms", "build_ms", "fps", "timing"}


def _summary(tiny_demo):
    return json.loads((tiny_demo.out / "report" / "summary.json").read_text())


def _without_measurements(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {k: _without_measurements(v) for k, v in obj.items() if k not in MEASURED}
    if isinstance(obj, list):
        return [_without_measurements(v) for v in obj]
    return obj


def _fast_config(tmp_path):
    path = tmp_path / "fast.yaml"
    path.write_text(FAST)
    return path


def test_report_has_every_table_key_and_a_readable_png_per_figure(tiny_demo):
    summary = _summary(tiny_demo)
    assert {
        "bundle",
        "dataset",
        "embedder",
        "parameters",
        "segmentation",
        "retrieval",
        "regions",
        "memory",
        "navigation",
        "figures",
        "timing",
    } <= set(summary)
    for key in ("iou", "strict_accuracy", "relaxed_accuracy", "strict_precision", "relaxed_precision", "f1", "alpha"):
        assert all(key in m for m in summary["retrieval"]["methods"].values())
    for key in ("precision", "recall", "f1", "runtime_ms", "parameters", "per_query"):
        assert all(key in m for m in summary["regions"]["methods"].values())
    assert {"miou", "fw_miou", "f1", "fps"} <= set(next(iter(summary["segmentation"]["methods"].values())))
    text = (tiny_demo.out / "report" / "report.md").read_text()
    for heading in (
        "## Table I: terrain segmentation",
        "## Table II: open-set object retrieval",
        "## Table III: region monitoring",
        "## Memory of the saved map and graph",
        "## Navigation:",
        "## Figures",
    ):
        assert heading in text
    titles = set(summary["figures"])
    assert {
        "Terrain map vs ground truth",
        "Places layer by terrain",
        "Retrieved boxes vs ground truth",
        "Terrain-aware navigation",
        "Memory",
    } <= titles
    assert any(t.startswith("Region levels") for t in titles)
    for rel in summary["figures"].values():
        with Image.open(tiny_demo.out / "report" / rel) as im:
            im.verify()
        with Image.open(tiny_demo.out / "report" / rel) as im:
            assert im.format == "PNG" and min(im.size) >= 300
            pixels = np.asarray(im.convert("RGB"))[::7, ::7].reshape(-1, 3)
            assert len(np.unique(pixels, axis=0)) > 8  # not blank


def test_region_truth_is_the_places_inside_each_polygon(tiny_demo):
    from terra.bundle import Bundle
    from terra.graph.storage import load_scene_graph

    graph = load_scene_graph(Bundle(tiny_demo.bundle))
    regions = json.loads((tiny_demo.dataset / "ground_truth" / "regions.json").read_text())["regions"]
    summary = _summary(tiny_demo)["regions"]
    # Closed polygons (places on an edge count): matplotlib's test on the polygon grown by 1 mm
    # (the sign of `radius` that grows it depends on the orientation, so both are tried).
    xy = graph.places.position[:, :2]
    paths = [MplPath(np.asarray(r["polygon"])) for r in regions]
    counts = [int((p.contains_points(xy, radius=2e-3) | p.contains_points(xy, radius=-2e-3)).sum()) for p in paths]
    assert [q["num_gt_places"] for q in summary["queries"]] == counts
    assert [q["description"] for q in summary["queries"]] == [r["description"] for r in regions]
    for m in summary["methods"].values():
        tp = sum(q["tp"] for q in m["per_query"])
        fp = sum(q["fp"] for q in m["per_query"])
        fn = sum(q["fn"] for q in m["per_query"])
        assert [q["tp"] + q["fn"] for q in m["per_query"]] == counts
        assert m["precision"] == pytest.approx(tp / (tp + fp) if tp + fp else 0.0)
        assert m["recall"] == pytest.approx(tp / (tp + fn))


def test_retrieval_truth_and_memory_match_the_files(tiny_demo):
    summary = _summary(tiny_demo)
    objects = json.loads((tiny_demo.dataset / "ground_truth" / "objects.json").read_text())["objects"]
    classes = sorted({o["class_name"] for o in objects} - {"building", "tree", "crosswalk"})
    assert summary["retrieval"]["queries"] == [f"Find the {c}" for c in classes]
    assert summary["retrieval"]["num_gt"] == sum(o["class_name"] in classes for o in objects)
    on_disk = sum(os.path.getsize(os.path.join(d, f)) for d, _, files in os.walk(tiny_demo.bundle) for f in files)
    assert summary["memory"]["total_bytes"] == on_disk
    assert summary["memory"]["bytes_per_m2"] == pytest.approx(on_disk / summary["memory"]["area_m2"])


def test_tuned_parameters_are_the_best_on_the_validation_scene_and_reproduce_there(tiny_demo):
    from terra.eval.config import EvalConfig
    from terra.eval.inputs import EvalInputs
    from terra.eval.regions import MonitorParams, region_truth
    from terra.eval.retrieval import retrieval_task, run_retrieval
    from terra.eval.runner import monitoring_run
    from terra.eval.tuning import TunedParameters, alpha_grid

    tuned = TunedParameters.load(tiny_demo.validation / "tuned.json")
    val = EvalInputs.load(tiny_demo.validation / "map.terra", tiny_demo.validation / "dataset")
    config = EvalConfig()
    task = retrieval_task(val.gt, config.retrieval)
    f1 = [
        run_retrieval(val.msm, val.graph, task.queries, "ms-avg", a, val.embedder).evaluate(task).f1
        for a in alpha_grid(config.tune)
    ]
    assert tuned.retrieval["ms-avg"]["f1"] == pytest.approx(max(f1))
    assert tuned.retrieval["ms-avg"]["alpha"] == alpha_grid(config.tune)[int(np.argmax(f1))]
    truth = region_truth(val.graph, val.gt.regions)
    for method in ("aib", "agglomerative"):
        entry = tuned.monitoring[method]
        params = MonitorParams(entry["alpha"], entry.get("k"), entry.get("levels"), entry.get("min_level"))
        run = monitoring_run(val, method, truth, params, config.regions.monitor_method)
        assert run.total.f1 == pytest.approx(entry["f1"])


def test_tuned_parameters_record_the_query_mode_and_are_refused_under_another(tiny_demo, tmp_path):
    from terra.errors import TerraError
    from terra.eval.runner import evaluate
    from terra.eval.tuning import TunedParameters
    from terra.tasks.config import TasksConfig

    tuned = TunedParameters.load(tiny_demo.validation / "tuned.json")
    assert tuned.monitoring and all(entry["query"] == "sentence" for entry in tuned.monitoring.values())
    out = tmp_path / "report"
    phrases = TasksConfig.model_validate({"monitoring": {"query": "phrases"}})
    with pytest.raises(TerraError, match="query 'sentence' but the configuration has 'phrases'"):
        evaluate(tiny_demo.bundle, tiny_demo.dataset, out, tuned=tuned, tasks_config=phrases, show_progress=False)
    assert not out.exists()


def test_aib_null_score_changes_what_aib_returns(tiny_demo):
    from terra.eval.inputs import EvalInputs
    from terra.eval.regions import MonitorParams, region_truth
    from terra.eval.runner import monitoring_run

    val = EvalInputs.load(tiny_demo.validation / "map.terra", tiny_demo.validation / "dataset")
    truth = region_truth(val.graph, val.gt.regions)
    low, high = (monitoring_run(val, "aib", truth, MonitorParams(a), "mix") for a in (0.05, 0.9))
    assert sum(len(p) for p in low.predicted) > sum(len(p) for p in high.predicted)


def test_eval_cli_is_deterministic_apart_from_runtimes(tiny_demo, tmp_path):
    config = _fast_config(tmp_path)
    tuned = tiny_demo.validation / "tuned.json"
    summaries = []
    for name in ("a", "b"):
        code, stdout, stderr = run_cli(
            [
                "eval",
                str(tiny_demo.bundle),
                "--gt",
                str(tiny_demo.dataset),
                "--tuned",
                str(tuned),
                "--config",
                str(config),
                "--out",
                str(tmp_path / name),
                "-q",
            ]
        )
        assert code == 0, stderr
        assert f"report: {tmp_path / name / 'report.md'}" in stdout
        summaries.append(json.loads((tmp_path / name / "summary.json").read_text()))
    assert _without_measurements(summaries[0]) == _without_measurements(summaries[1])
    reference = _without_measurements(_summary(tiny_demo))
    for key in ("retrieval", "regions", "navigation", "memory", "parameters"):
        assert _without_measurements(summaries[0])[key] == reference[key]


def _assert_one_line_error(code, stderr, pattern):
    assert code == 2
    assert stderr.strip().count("\n") == 0 and "Traceback" not in stderr
    assert pattern in stderr


def test_eval_bad_input_one_line_exit_2_and_no_report(tiny_demo, tmp_path):
    from terra.bundle import Bundle, BundleWriter
    from terra.eval.tuning import TunedParameters

    out = tmp_path / "report"
    empty = tmp_path / "not-a-dataset"
    empty.mkdir()
    cases = [
        (["--gt", str(empty)], "no ground truth folder"),
        (["--gt", str(tiny_demo.validation / "dataset")], "not the dataset"),  # its frames differ
    ]
    no_graph = tmp_path / "map-only.terra"
    writer = BundleWriter(no_graph, base=Bundle(tiny_demo.bundle), drop_components=("graph",))
    writer.commit()
    on_test = TunedParameters.load(tiny_demo.validation / "tuned.json")
    on_test.validation = {"dataset": "sim-tiny-seed0"}
    tuned_on_test = on_test.save(tmp_path / "tuned-on-test.json")
    for extra, pattern in cases:
        code, _, stderr = run_cli(["eval", str(tiny_demo.bundle), *extra, "--out", str(out), "-q"])
        _assert_one_line_error(code, stderr, pattern)
    code, _, stderr = run_cli(["eval", str(no_graph), "--gt", str(tiny_demo.dataset), "--out", str(out), "-q"])
    _assert_one_line_error(code, stderr, "no scene graph")
    code, _, stderr = run_cli(
        [
            "eval",
            str(tiny_demo.bundle),
            "--gt",
            str(tiny_demo.dataset),
            "--tuned",
            str(tuned_on_test),
            "--out",
            str(out),
            "-q",
        ]
    )
    _assert_one_line_error(code, stderr, "the scene under test")
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map-only.terra", "not-a-dataset", "tuned-on-test.json"]
    # A folder that is not a report is never replaced, even with --overwrite.
    (empty / "notes.txt").write_text("mine")
    code, _, stderr = run_cli(
        ["eval", str(tiny_demo.bundle), "--gt", str(tiny_demo.dataset), "--out", str(empty), "-q"]
    )
    _assert_one_line_error(code, stderr, "exists (pass --overwrite to replace it)")
    code, _, stderr = run_cli(
        ["eval", str(tiny_demo.bundle), "--gt", str(tiny_demo.dataset), "--out", str(empty), "-q", "--overwrite"]
    )
    _assert_one_line_error(code, stderr, "is not an evaluation report folder")
    assert [p.name for p in empty.iterdir()] == ["notes.txt"]


def test_a_failure_midway_leaves_no_partial_report_and_keeps_the_old_one(tiny_demo, tmp_path, monkeypatch):
    import terra.eval.report_figures
    from terra.eval.runner import evaluate
    from terra.eval.tuning import TunedParameters

    def broken(*args, **kwargs):
        raise RuntimeError("figure failed")

    monkeypatch.setattr(terra.eval.report_figures, "write_figures", broken)
    tuned = TunedParameters.load(tiny_demo.validation / "tuned.json")
    out = tmp_path / "report"
    with pytest.raises(RuntimeError, match="figure failed"):
        evaluate(tiny_demo.bundle, tiny_demo.dataset, out, tuned=tuned, show_progress=False)
    assert list(tmp_path.iterdir()) == []
    out.mkdir()
    (out / "summary.json").write_text("{}")  # an earlier report
    with pytest.raises(RuntimeError):
        evaluate(tiny_demo.bundle, tiny_demo.dataset, out, tuned=tuned, show_progress=False)
    assert [p.name for p in tmp_path.iterdir()] == ["report"] and (out / "summary.json").read_text() == "{}"


def test_tune_and_tuned_together_are_refused(tiny_demo, tmp_path):
    code, _, stderr = run_cli(
        [
            "eval",
            str(tiny_demo.bundle),
            "--gt",
            str(tiny_demo.dataset),
            "--tune",
            "--tuned",
            "x.json",
            "--out",
            str(tmp_path / "r"),
        ]
    )
    _assert_one_line_error(code, stderr, "give one of them")
