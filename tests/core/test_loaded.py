"""LoadedBundle: one opened bundle loaded on demand, the per-map data stored at map time equal to
what a query process would compute, and older bundles without it still answering."""

from __future__ import annotations

import json

import numpy as np
import pytest

from terra.bundle import BundleWriter
from terra.loaded import LoadedBundle
from terra.mapping.semantic_map import ms_avg_norms, ms_max_ids
from terra.tasks.commands import find, plan
from terra.tasks.requests import FindRequest, PlanRequest
from tests.tasks.test_tasks_synthetic import dumpster_lot


@pytest.fixture
def lot(text_embedder, tmp_path):
    from terra.graph.storage import write_scene_graph
    from terra.mapping.storage import write_map

    msm, graph, _ = dumpster_lot(text_embedder)
    with BundleWriter(tmp_path / "lot.terra") as w:
        write_map(w, msm)
        write_scene_graph(w, graph)
    return tmp_path / "lot.terra"


def test_stored_per_point_data_equals_the_recomputed(lot):
    msm = LoadedBundle(lot).msm
    assert msm._avg_norm is not None and msm._max_id is not None  # read from the bundle, not computed
    np.testing.assert_array_equal(msm.ms_avg_norms(), ms_avg_norms(msm.counts, msm.bank))
    np.testing.assert_array_equal(msm.ms_max_ids(), ms_max_ids(msm.counts))


def test_a_bundle_without_stored_norms_still_answers_the_same(lot, tmp_path):
    from terra.bundle import Bundle

    request = FindRequest(queries=["find the dumpster"], alpha=0.4)
    with_norms = find(LoadedBundle(lot), request).to_json()
    old = tmp_path / "old.terra"
    with BundleWriter(old, base=Bundle(lot)) as w:
        w.remove("map/ms_avg_norm")
        w.remove("map/ms_max_id")
    loaded = LoadedBundle(old)
    assert loaded.msm._avg_norm is None
    without = find(loaded, request).to_json()
    assert without["objects"] == with_norms["objects"]


def test_a_mis_shaped_stored_array_is_refused(lot, tmp_path):
    from terra.bundle import Bundle
    from terra.errors import TerraError

    bad = tmp_path / "bad.terra"
    with BundleWriter(bad, base=Bundle(lot)) as w:
        w.put_array("map/ms_avg_norm", np.zeros(3, dtype=np.float32))
    with pytest.raises(TerraError, match=r"ms_avg_norm.npy: array of shape \(3,\), expected float32"):
        _ = LoadedBundle(bad).msm


def test_loads_only_what_a_query_needs_and_caches_cost_graphs(lot):
    loaded = LoadedBundle(lot)
    first = plan(loaded, PlanRequest(to_node=0, from_node=63, forbid=["asphalt"]))
    assert loaded._msm is None and loaded._embedder is None  # a plan between places needs neither
    again = plan(loaded, PlanRequest(to_node=0, from_node=63, forbid=["asphalt"]))
    assert len(loaded._cost_graphs) == 1 and again.to_json() == first.to_json()
    plan(loaded, PlanRequest(to_node=0, from_node=63))
    assert len(loaded._cost_graphs) == 2


def test_update_graph_is_atomic_and_seen_by_later_queries(lot):
    from terra.bundle import Bundle
    from terra.graph.storage import load_scene_graph

    loaded = LoadedBundle(lot)
    result = find(loaded, FindRequest(queries=["find the dumpster"], alpha=0.4, save=True))
    graph = loaded.graph
    assert graph is not None
    assert result.saved and len(graph.objects) == len(result.objects) == 2
    Bundle(lot).verify()
    assert load_scene_graph(Bundle(lot)).objects.label == graph.objects.label
    manifest = json.loads((lot / "manifest.json").read_text())
    assert manifest["components"]["graph"]["objects"] == 2
