"""Session fixture of the interop tests: the tiny campus bundle with its graph and three objects
placed by hand (the graph fixtures have none), so every layer of an export is exercised."""

from __future__ import annotations

import numpy as np
import pytest

from terra.bundle import Bundle, BundleWriter
from terra.graph.scene_graph import Objects
from terra.graph.storage import load_scene_graph, write_scene_graph
from tests.graph.fixtures import copy_bundle


@pytest.fixture(scope="session")
def interop_bundle(tiny_graph_bundle, tmp_path_factory) -> Bundle:
    path = copy_bundle(tiny_graph_bundle, tmp_path_factory.mktemp("interop") / "tiny.terra")
    graph = load_scene_graph(Bundle(path))
    places = graph.places.position
    graph.objects = Objects(
        center=places[[0, 5, 9]] + np.array([0.5, -0.3, 0.4]),
        size=np.array([[1.0, 2.0, 0.8], [0.6, 0.6, 1.0], [3.0, 1.5, 2.0]]),
        yaw=np.array([0.3, -1.2, 2.0]),
        label=["bench", "trash can", "bench"],
        score=np.array([0.61, 0.55, 0.47], dtype=np.float32),
        point_count=np.array([40, 12, 77]),
        place=np.array([0, 5, 9]),
    )
    writer = BundleWriter(path, base=Bundle(path))
    write_scene_graph(writer, graph)
    return writer.commit()
