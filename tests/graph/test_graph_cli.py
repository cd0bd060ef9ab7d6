"""`terra build` through the CLI: the summary, --regions, and bad input (one clear line, exit code
2, the bundle unchanged)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from terra.bundle import MANIFEST, Bundle, BundleWriter
from terra.cli import run
from terra.errors import TerraError
from terra.graph.storage import load_scene_graph
from tests.graph.fixtures import copy_bundle


def folder_state(path: Path) -> dict[str, str]:
    """SHA-256 of every file under the bundle's parent folder (catches leftover temporaries too)."""
    return {
        str(p.relative_to(path.parent)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(path.parent.rglob("*"))
        if p.is_file()
    }


def fails_cleanly(argv: list[str], bundle: Path, capsys, expect: str) -> str:
    before = folder_state(bundle)
    code = run(argv)
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert expect in err, err
    assert folder_state(bundle) == before
    return err


@pytest.fixture
def tiny_copy(tiny_bundle, tmp_path) -> Path:
    return copy_bundle(tiny_bundle, tmp_path / "work" / "tiny.terra")


def test_build_prints_a_json_summary_and_honours_regions(tiny_copy, capsys):
    assert run(["build", str(tiny_copy), "--regions", "spectral", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    graph = load_scene_graph(Bundle(tiny_copy))
    assert summary["places"] == len(graph.places) > 0
    assert summary["region_method"] == graph.region_method == "spectral"
    assert summary["regions_per_level"] == [len(level) for level in graph.regions]
    assert set(summary["seconds"]) >= {"terrain grid", "GVD places", "write"}
    before = folder_state(tiny_copy)
    assert run(["build", str(tiny_copy), "--quiet"]) == 2  # an existing graph is kept ...
    assert "has a scene graph already (pass --overwrite to replace it)" in capsys.readouterr().err
    assert folder_state(tiny_copy) == before
    assert run(["build", str(tiny_copy), "--quiet", "--overwrite"]) == 0  # ... unless --overwrite
    assert load_scene_graph(Bundle(tiny_copy)).region_method == "agglomerative"


def test_build_help_has_an_example(capsys):
    assert run(["build", "--help"]) == 0
    assert "Example: terra build" in capsys.readouterr().out


def test_a_map_without_terrain_points(tiny_copy, tmp_path, capsys):
    base = Bundle(tiny_copy)
    votes = np.zeros_like(base.array("map/terrain_votes"))
    votes[0, 0] = 1  # one vote, for the first class: the map has terrain votes, none of the second
    writer = BundleWriter(tiny_copy, base=base)
    writer.put_array("map/terrain_votes", votes)
    writer.commit()
    config = tmp_path / "terra.yaml"
    config.write_text(f"build:\n  terrain:\n    include: [{base.model.terrain_classes[1]}]\n")
    fails_cleanly(["build", str(tiny_copy), "--config", str(config)], tiny_copy, capsys, "no terrain points")


def test_a_map_whose_votes_were_all_lost_builds_on_lidar_ground(tiny_copy, capsys):
    # Without a single terrain vote the map is a LiDAR-only one (terra.graph.ground).
    base = Bundle(tiny_copy)
    writer = BundleWriter(tiny_copy, base=base)
    writer.put_array("map/terrain_votes", np.zeros_like(base.array("map/terrain_votes")))
    writer.commit()
    assert run(["build", str(tiny_copy)]) == 0
    graph = load_scene_graph(Bundle(tiny_copy))
    assert graph.terrain_classes == ["ground"] and len(graph.places) > 10 and graph.has_edge_geometry


def test_configured_terrain_classes_missing_from_the_map(tiny_copy, tmp_path, capsys):
    config = tmp_path / "terra.yaml"
    config.write_text("build:\n  terrain:\n    include: [sidewalk, lava]\n")
    err = fails_cleanly(
        ["build", str(tiny_copy), "--config", str(config)], tiny_copy, capsys, "'lava' is not in the map"
    )
    assert "sidewalk" in err  # names what the map has


def test_a_manifest_that_drops_the_maps_terrain_classes(tiny_copy, capsys):
    # A map without terrain classes builds (on LiDAR ground, tests/graph/test_graph_ground.py);
    # a manifest that no longer matches its arrays is refused.
    manifest = json.loads((tiny_copy / MANIFEST).read_text())
    manifest["terrain_classes"] = []
    (tiny_copy / MANIFEST).write_text(json.dumps(manifest))
    fails_cleanly(["build", str(tiny_copy)], tiny_copy, capsys, "terrain_votes.npy: array of shape")


def test_a_bundle_of_an_incompatible_schema_version(tiny_copy, capsys):
    manifest = json.loads((tiny_copy / MANIFEST).read_text())
    manifest["schema_version"] = 99
    (tiny_copy / MANIFEST).write_text(json.dumps(manifest))
    fails_cleanly(["build", str(tiny_copy)], tiny_copy, capsys, "schema_version 99 is not supported")


def test_bad_options_and_paths(tiny_copy, tmp_path, capsys):
    fails_cleanly(["build", str(tiny_copy), "--regions", "kmeans"], tiny_copy, capsys, "--regions")
    config = tmp_path / "bad.yaml"
    config.write_text("build:\n  regions:\n    cuts: [100, 50]\n")
    fails_cleanly(["build", str(tiny_copy), "--config", str(config)], tiny_copy, capsys, "cuts")
    assert run(["build", str(tmp_path / "missing.terra")]) == 2
    assert "not a Terra bundle" in capsys.readouterr().err


def test_a_graph_of_another_format_is_refused_on_load(tiny_graph_bundle, tmp_path):
    path = copy_bundle(tiny_graph_bundle, tmp_path / "old.terra")
    manifest = json.loads((path / MANIFEST).read_text())
    manifest["components"]["graph"]["format"] = 0
    (path / MANIFEST).write_text(json.dumps(manifest))
    with pytest.raises(TerraError, match="scene graph format 0 is not supported"):
        load_scene_graph(Bundle(path))


def test_build_cuts_reproduces_the_papers_fixed_levels(tiny_copy, capsys):
    """--cuts 50,100,200,400: the levels are scipy's average linkage on the paper's weight cut at
    those heights, computed independently here from the stored places."""
    from scipy.cluster.hierarchy import fcluster, linkage
    from scipy.spatial.distance import pdist

    assert run(["build", str(tiny_copy), "--cuts", "50,100,200,400", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    graph = load_scene_graph(Bundle(tiny_copy))
    unit = graph.places.embedding / np.linalg.norm(graph.places.embedding, axis=1, keepdims=True)
    weight = pdist(graph.places.position) + 100.0 * (1.0 - (unit @ unit.T)[np.triu_indices(len(unit), 1)])
    tree = linkage(weight, "average")
    for k, cut in enumerate((50.0, 100.0, 200.0, 400.0), start=1):
        expected = fcluster(tree, cut, "distance")
        got = graph.place_region(k)
        pairs = np.unique(np.column_stack([expected, got]), axis=0)
        assert len(pairs) == len(np.unique(expected)) == len(np.unique(got))  # the same partition
    assert summary["regions_per_level"] == [len(level) for level in graph.regions]
    fails_cleanly(
        ["build", str(tiny_copy), "--cuts", "50,x"], tiny_copy, capsys, "--cuts expects comma-separated numbers"
    )
    fails_cleanly(
        ["build", str(tiny_copy), "--cuts", "100,50"], tiny_copy, capsys, "cuts must be a non-empty list of increasing"
    )
