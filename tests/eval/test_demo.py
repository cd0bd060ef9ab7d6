"""`terra demo --preset tiny` end to end, in-process (the session fixture `tiny_demo` runs it once)."""

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from tests.eval.fixtures import run_cli


def _summary(demo):
    return json.loads((demo.out / "report" / "summary.json").read_text())


def test_demo_writes_the_report_and_prints_its_figures(tiny_demo):
    assert tiny_demo.exit_code == 0, tiny_demo.stderr
    report = tiny_demo.out / "report"
    assert (report / "report.md").is_file() and (report / "summary.json").is_file()
    summary = _summary(tiny_demo)
    for rel in summary["figures"].values():
        assert (report / rel).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    printed = tiny_demo.stdout
    assert f"report: {tiny_demo.out / 'report' / 'report.md'}" in printed
    # Every retrieval / region figure printed is the one in summary.json.
    rows = re.findall(
        r"retrieval (\S+)\s+\((\d+) objects, (\d+) queries\): IoU ([\d.]+) \(matched ([\d.]+)\), RAcc ([\d.]+), "
        r"RPrec ([\d.]+), F1 ([\d.]+)",
        printed,
    )
    assert {r[0] for r in rows} == set(summary["retrieval"]["methods"])
    for name, n_obj, n_q, iou, matched, racc, rprec, f1 in rows:
        m = summary["retrieval"]["methods"][name]
        assert int(n_obj) == summary["retrieval"]["num_gt"] and int(n_q) == len(summary["retrieval"]["queries"])
        keys = ("iou", "matched_iou", "relaxed_accuracy", "relaxed_precision", "f1")
        assert (iou, matched, racc, rprec, f1) == tuple(f"{m[k]:.3f}" for k in keys)
    regions = re.findall(r"regions (\S+)\s*: P ([\d.]+), R ([\d.]+), F1 ([\d.]+)", printed)
    assert {r[0] for r in regions} == {"aib", "spectral", "agglomerative"}
    for name, p, r, f1 in regions:
        m = summary["regions"]["methods"][name]
        assert (p, r, f1) == (f"{m['precision']:.3f}", f"{m['recall']:.3f}", f"{m['f1']:.3f}")
    for name, plan in summary["navigation"]["plans"].items():
        assert f"path {name}: {plan['length_m']:.1f} m" in printed


def test_demo_finds_the_dumpster_and_the_bicycle_rack_near_ground_truth(tiny_demo):
    demo = json.loads((tiny_demo.out / "demo.json").read_text())
    objects = json.loads((tiny_demo.dataset / "ground_truth" / "objects.json").read_text())["objects"]
    for query, cls in (("Find the dumpster", "dumpster"), ("Get bike from the bicycle rack", "bicycle rack")):
        truth = np.array([o["center"][:2] for o in objects if o["class_name"] == cls])
        assert len(truth), f"the tiny campus has a {cls}"
        (found,) = [f for f in demo["tasks"]["find"] if f["query"] == query]
        distance = np.linalg.norm(truth - np.asarray(found["best"]["center"][:2]), axis=1).min()
        assert distance < 2.0
        c = found["best"]["center"]
        assert f"find {query!r}: object at ({c[0]:.1f}, {c[1]:.1f}, {c[2]:.1f}) m" in tiny_demo.stdout
    plan = demo["tasks"]["plan"]
    assert "error" not in plan and plan["prefer"] == ["sidewalk"]
    assert abs(sum(plan["length_by_terrain"].values()) - plan["length_m"]) < 1e-3  # JSON rounds to 0.1 mm
    # The plan task and the evaluation's "prefer sidewalk" plan are the same path.
    assert abs(_summary(tiny_demo)["navigation"]["plans"]["prefer sidewalk"]["length_m"] - plan["length_m"]) < 1e-3


def test_demo_parameters_come_from_the_validation_seed(tiny_demo):
    tuned = json.loads((tiny_demo.validation / "tuned.json").read_text())
    assert tuned["validation"]["dataset"] == "sim-tiny-seed1"
    summary = _summary(tiny_demo)
    assert summary["dataset"] == "sim-tiny-seed0"
    assert summary["parameters"]["source"] == "tuned on validation scene sim-tiny-seed1"
    for method, m in summary["retrieval"]["methods"].items():
        assert m["alpha"] == tuned["retrieval"][method]["alpha"]
    for method, m in summary["regions"]["methods"].items():
        assert f"alpha={tuned['monitoring'][method]['alpha']:g}" in m["parameters"]
    # The validation scene is the cheaper one: frames twice as far apart.
    n_test = json.loads((tiny_demo.dataset / "terra_dataset.json").read_text())["frames"]
    n_val = json.loads((tiny_demo.validation / "dataset" / "terra_dataset.json").read_text())["frames"]
    assert n_val < n_test


def test_demo_rerun_resumes_from_the_caches(tiny_demo, monkeypatch):
    import terra.graph.pipeline
    import terra.mapping.pipeline
    import terra.sim

    def refuse(*args, **kwargs):
        raise AssertionError("a cached step was redone")

    for module, name in (
        (terra.sim, "simulate"),
        (terra.mapping.pipeline, "build_map"),
        (terra.graph.pipeline, "build_graph"),
    ):
        monkeypatch.setattr(module, name, refuse)
    report = tiny_demo.out / "report" / "summary.json"
    before = report.read_bytes(), (tiny_demo.out / "demo.json").read_bytes()
    code, stdout, stderr = run_cli(["demo", "--out", str(tiny_demo.out), "--preset", "tiny"])
    assert code == 0, stderr
    assert (report.read_bytes(), (tiny_demo.out / "demo.json").read_bytes()) == before
    assert stdout == tiny_demo.stdout
    assert "test: simulate (cached)" in stderr and "validation: tune alpha and k (cached)" in stderr


def test_demo_redoes_only_the_steps_whose_configuration_changed(tiny_demo, tmp_path, monkeypatch):
    import terra.sim

    out = tmp_path / "copy"
    shutil.copytree(tiny_demo.out, out)
    monkeypatch.setattr(terra.sim, "simulate", lambda *a, **k: (_ for _ in ()).throw(AssertionError("re-simulated")))
    config = tmp_path / "terra.yaml"
    config.write_text("eval:\n  figures: false\n  segmentation:\n    max_images: 0\n")
    code, stdout, stderr = run_cli(["demo", "--out", str(out), "--preset", "tiny", "--config", str(config), "--json"])
    assert code == 0, stderr
    steps = json.loads(stdout)["steps"]
    assert steps["test: map"] == "cached" and steps["validation: graph"] == "cached"
    assert steps["validation: tune alpha and k"] == "ran" and steps["test: tasks and evaluation"] == "ran"
    summary = json.loads((out / "report" / "summary.json").read_text())
    assert "figures" not in summary and "segmentation" not in summary
    assert not (out / "report" / "figures").exists()


def test_demo_bad_arguments_fail_with_one_line(tmp_path):
    code, _, stderr = run_cli(["demo", "--out", str(tmp_path / "d"), "--preset", "gigantic"])
    assert code == 2 and stderr.strip().count("\n") == 0 and "unknown preset 'gigantic'" in stderr
    assert not (tmp_path / "d").exists()


def test_the_demo_judges_a_find_by_table_twos_rule():
    """ "Found 0.5 m away" is not a hit when the box does not overlap the object: the summary says
    so, and quotes Table II's row for the same query."""
    from terra.datasets.ground_truth import GroundTruth, ObjectBox
    from terra.eval.demo import format_demo, nearest_gt_object

    truth = GroundTruth(
        [ObjectBox(1, 26, "dumpster", np.array([0.0, 0.0, 0.75]), np.array([2.0, 1.0, 1.5]), 0.0)], None, []
    )
    beside = {"center": [0.0, 0.5 + 0.8, 0.75], "size": [2.0, 0.2, 1.5], "yaw": 0.0}  # thin, 0.7 m off its side
    over = {"center": [0.5, 0.0, 0.75], "size": [2.0, 1.0, 1.5], "yaw": 0.0}  # shifted 0.5 m along its length
    miss = nearest_gt_object(np.array(beside["center"]), truth, "dumpster", beside)
    assert miss is not None
    assert miss["distance_m"] == 1.3 and miss["iou"] == 0.0 and miss["hit"] is False
    hit = nearest_gt_object(np.array(over["center"]), truth, "dumpster", over)
    assert hit is not None
    assert hit["iou"] == pytest.approx(1.5 / 2.5) and hit["hit"] is True  # overlap 1.5 x 1 x 1.5 of 2 x 1 x 1.5 each
    row = {"query": "Find the dumpster", "num_gt": 2, "num_predictions": 3, "relaxed_hits": 0}
    demo = {
        "test_scene": {"preset": "tiny", "seed": 0},
        "validation_scene": {"preset": "tiny", "seed": 1},
        "tasks": {
            "find": [
                {
                    "query": "Find the dumpster",
                    "method": "ms-avg",
                    "alpha": 0.4,
                    "best": {**beside, "score": 0.8},
                    "nearest_gt": miss,
                }
            ],
            "monitor": {
                "query": "q",
                "method": "mix",
                "parameters": {"k": 1},
                "places": 0,
                "regions": 1,
                "labelled_region": {"name": "service", "gt_places": 0, "precision": 0.0, "recall": 0.0},
            },
            "plan": {"to": "x", "prefer": ["sidewalk"], "error": "no path"},
        },
        "evaluation": {
            "parameters": {"source": "defaults"},
            "retrieval": {
                "queries": ["Find the dumpster"],
                "num_gt": 2,
                "methods": {
                    "ms-avg": {
                        "per_query": [row],
                        "iou": 0.0,
                        "relaxed_accuracy": 0.0,
                        "relaxed_precision": 0.0,
                        "f1": 0.0,
                    }
                },
            },
        },
        "report": "report/report.md",
    }
    lines = format_demo(demo, Path("out"))
    assert lines[1] == (
        "  find 'Find the dumpster': object at (0.0, 1.3, 0.8) m, score 0.80; nearest true dumpster 1.3 m away, "
        "box IoU 0.00: not a hit (the boxes do not overlap) (Table II, ms-avg: 3 found, 0 of 2 dumpsters hit)"
    )
    assert lines[2] == (
        "  monitor 'q': 0 places in 1 region (mix, k 1); "
        "labelled region 'service' is not evaluable (no place inside it)"
    )


def test_the_demo_says_which_perception_made_the_map(tiny_demo):
    report = (tiny_demo.out / "report" / "report.md").read_text()
    assert (
        "Perception: the `labels` backend" in report and "not comparable with the paper's CLIP/YOLO numbers" in report
    )
    assert "  perception: labels backend (the ground-truth label images with simulated noise)" in tiny_demo.stdout
    assert _summary(tiny_demo)["perception"]["ground_truth_masks"] is True


def _scores(summary: dict) -> dict:
    """What must not depend on where the dataset lives: the tables, without runtimes."""
    retrieval = {
        m: {k: v for k, v in s.items() if k != "runtime_ms"} for m, s in summary["retrieval"]["methods"].items()
    }
    regions = {m: (s["precision"], s["recall"], s["f1"]) for m, s in summary["regions"]["methods"].items()}
    return {
        "retrieval": retrieval,
        "regions": regions,
        "places": summary["places"],
        "memory": summary["memory"]["area_m2"],
    }


def test_a_renamed_copy_of_the_dataset_evaluates_like_the_original(tiny_demo, tmp_path):
    copy = Path(shutil.copytree(tiny_demo.dataset, tmp_path / "campus-copy"))
    meta = json.loads((copy / "terra_dataset.json").read_text())
    meta["name"] = "campus-copy"  # a name of its own, as a SemanticKITTI folder's would be
    (copy / "terra_dataset.json").write_text(json.dumps(meta))
    config = tmp_path / "fast.yaml"
    config.write_text("eval:\n  figures: false\n  segmentation:\n    max_images: 0\n")
    tuned = tiny_demo.validation / "tuned.json"
    code, out, err = run_cli(
        [
            "eval",
            str(tiny_demo.bundle),
            "--gt",
            str(copy),
            "--tuned",
            str(tuned),
            "--out",
            str(tmp_path / "report"),
            "--config",
            str(config),
            "--json",
        ]
    )
    assert code == 0, err
    summary = json.loads(out)
    assert summary["dataset"] == "campus-copy"
    assert _scores(summary) == _scores(_summary(tiny_demo))
    # Another scene is refused whatever it is called; parameters tuned on a renamed copy of the
    # validation scene are recognised as tuned on it.
    code, _, err = run_cli(
        [
            "eval",
            str(tiny_demo.bundle),
            "--gt",
            str(tiny_demo.validation / "dataset"),
            "--out",
            str(tmp_path / "other"),
            "--config",
            str(config),
        ]
    )
    assert code == 2 and "not the dataset" in err and not (tmp_path / "other").exists()
    val_copy = Path(shutil.copytree(tiny_demo.validation / "dataset", tmp_path / "val-copy"))
    meta = json.loads((val_copy / "terra_dataset.json").read_text())
    meta["name"] = "val-copy"
    (val_copy / "terra_dataset.json").write_text(json.dumps(meta))
    code, _, err = run_cli(
        [
            "eval",
            str(tiny_demo.validation / "map.terra"),
            "--gt",
            str(val_copy),
            "--tuned",
            str(tuned),
            "--out",
            str(tmp_path / "val"),
            "--config",
            str(config),
        ]
    )
    assert code == 2 and "were tuned on the scene under test" in err


def test_demo_live_replays_the_test_drive_to_the_batch_answer(tiny_demo):
    """`terra demo --live`: the replayed drive's map equals the demo's test map byte for byte, and the final
    live answer to the plan's target is the demo's own (the same best object, the same distance to truth)."""
    import json

    from tests.live.test_session import map_files

    code, stdout, stderr = run_cli(["demo", "--out", str(tiny_demo.out), "--preset", "tiny", "--live", "--speed", "0"])
    assert code == 0, stderr
    scene = tiny_demo.out / "tiny-seed0"
    assert map_files(scene / "live.terra") == map_files(scene / "map.terra")
    live = json.loads((tiny_demo.out / "report" / "live.json").read_text())
    assert [a["at_s"] for a in live["answers"]] == sorted(a["at_s"] for a in live["answers"]) and len(
        live["answers"]
    ) == 3
    demo = json.loads((tiny_demo.out / "demo.json").read_text())
    batch = next(f for f in demo["tasks"]["find"] if f["query"] == "Get bike from the bicycle rack")
    assert live["final"]["found"] == batch["objects"] > 0
    assert live["final"]["distance_m"] == batch["nearest_gt"]["distance_m"]
    assert "(final)" in stdout and (tiny_demo.out / "report" / "live.md").is_file()
