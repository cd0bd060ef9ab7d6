"""`terra demo --preset tiny` end to end, in-process (the session fixture `tiny_demo` runs it once)."""

import json
import re
import shutil

import numpy as np

from tests.fixtures_eval import run_cli


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
    rows = re.findall(r"retrieval (\S+)\s+\((\d+) objects, (\d+) queries\): IoU ([\d.]+) \(matched ([\d.]+)\), RAcc ([\d.]+), "
                      r"RPrec ([\d.]+), F1 ([\d.]+)", printed)
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

    for module, name in ((terra.sim, "simulate"), (terra.mapping.pipeline, "build_map"), (terra.graph.pipeline, "build_graph")):
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
