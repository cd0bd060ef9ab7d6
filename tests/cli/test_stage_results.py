"""Every stage's `--json` parses back into its typed result (terra/*/results.py) and equals it:
`terra sim`, `map`, `build`, `eval` (the report, --tune, --terrain-only), `export` and `import`
on a few frames of the tiny campus."""

from __future__ import annotations

import json

import pytest

from terra.cli import run
from terra.eval.results import EvalResult, TerrainTable, TuneResult
from terra.graph.results import BuildResult
from terra.interop.results import ExportResult, ImportResult
from terra.mapping.results import MapResult, PerceptionResult
from terra.sim.results import SimResult


def _json(capsys, argv: list[str]) -> dict:
    capsys.readouterr()
    assert run(argv) == 0
    return json.loads(capsys.readouterr().out)


def _round_trip(result_type, data: dict) -> None:
    """`data` read into `result_type` gives the same JSON back, and reading that again an equal result."""
    result = result_type.from_json(data)
    again = json.loads(json.dumps(result.to_json(), sort_keys=True))
    assert again == data
    assert result_type.from_json(again) == result


def test_sim_map_build_export_json_round_trip(tmp_path, capsys):
    data = tmp_path / "data"
    sim = _json(capsys, ["sim", "--preset", "tiny", "--max-frames", "8", "--out", str(data), "--json"])
    assert sim["frames"] == 8 and sim["folder"] == str(data)
    _round_trip(SimResult, sim)

    bundle = tmp_path / "campus.terra"
    mapped = _json(capsys, ["map", str(data), "--out", str(bundle), "--json"])
    assert mapped["bundle"] == str(bundle) and mapped["points"] > 0 and mapped["cache"] is None
    _round_trip(MapResult, mapped)

    built = _json(capsys, ["build", str(bundle), "--json"])
    assert set(built) == {"bundle", "places", "place_edges", "regions_per_level", "region_method", "stats", "seconds"}
    assert built["stats"]["edges"]["gvd"] >= 0 and "grid_cells" in built["stats"]
    _round_trip(BuildResult, built)

    report = _json(capsys, ["eval", str(bundle), "--gt", str(data), "--out", str(tmp_path / "report"), "--json"])
    assert {"bundle", "dataset", "parameters", "retrieval", "memory", "timing"} <= set(report)
    _round_trip(EvalResult, report)
    tuned = _json(capsys, ["eval", str(bundle), "--gt", str(data), "--tune", "--out", str(tmp_path / "val"), "--json"])
    assert tuned["schema"] and "retrieval" in tuned
    _round_trip(TuneResult, tuned)
    table = _json(capsys, ["eval", "--terrain-only", str(data), "--max-images", "4", "--json", "-q"])
    assert table["images"] == 4 and table["methods"]
    _round_trip(TerrainTable, table)

    out = tmp_path / "campus.dsg.json"
    exported = _json(capsys, ["export", str(bundle), "--format", "spark-dsg", "--out", str(out), "--json"])
    assert exported["format"] == "spark-dsg" and exported["out"] == str(out) and "layers" in exported
    _round_trip(ExportResult, exported)


def test_perception_only_json_round_trip(tmp_path, capsys):
    data = tmp_path / "data"
    assert run(["sim", "--preset", "tiny", "--max-frames", "3", "--out", str(data), "-q"]) == 0
    cache, config = tmp_path / "cache", tmp_path / "cache-on.yaml"
    config.write_text('mapping:\n  perception:\n    cache:\n      mode: "on"\n')
    args = [
        "map",
        str(data),
        "-o",
        str(tmp_path / "x.terra"),
        "-c",
        str(config),
        "--perception-only",
        "--cache",
        str(cache),
    ]
    filled = _json(capsys, [*args, "--json"])
    assert filled["frames"] == 3 and filled["folder"].startswith(str(cache))
    _round_trip(PerceptionResult, filled)


def test_import_json_round_trip(tmp_path, capsys, interop_bundle):
    pytest.importorskip("torch")
    theirs = tmp_path / "ms_map_out"
    assert run(["export", str(interop_bundle.path), "-f", "terra-reference", "-o", str(theirs)]) == 0
    imported = _json(
        capsys, ["import", str(theirs), "-f", "terra-reference", "-o", str(tmp_path / "b.terra"), "--json"]
    )
    assert imported["format"] == "terra-reference" and imported["points"] > 0
    _round_trip(ImportResult, imported)
