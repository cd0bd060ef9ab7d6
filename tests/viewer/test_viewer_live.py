"""`terra view --live`: a viewer open on a growing bundle draws each new version in place."""

from __future__ import annotations

import numpy as np
import pytest

from terra.live import Session
from terra.loaded import LoadedBundle
from terra.viewer import scene

viser = pytest.importorskip("viser")


def test_refresh_draws_the_newest_version(tiny_campus, tmp_path, text_embedder):
    from terra.viewer.app import TerraViewer, free_port

    out = tmp_path / "live.terra"
    session = Session(out, tiny_campus.classes, name=tiny_campus.name)
    for i in range(24):
        session.add(tiny_campus[i])
    first = session.snapshot()
    viewer = TerraViewer(LoadedBundle(out, embedder=text_embedder), port=free_port("127.0.0.1"))
    try:
        assert viewer.version == first.version and not viewer.refresh()  # nothing new yet
        first_points = len(viewer.msm)
        for i in range(24, len(tiny_campus)):
            session.add(tiny_campus[i])
        latest = session.snapshot()
        assert viewer.refresh() and viewer.version == latest.version
        msm, graph = latest.bundle.msm, latest.bundle.graph
        assert len(viewer.msm) == len(msm) > first_points
        rows = scene.display_subset(len(msm), viewer.max_points)
        np.testing.assert_array_equal(viewer.points.points, msm.points[rows])
        assert graph is not None and viewer.graph is not None
        drawn_places = viewer.layers["places"][0].points
        np.testing.assert_allclose(drawn_places, graph.places.position + [0.0, 0.0, 1.0], atol=1e-5)
        images = msm.images
        assert len(scene.trajectory_segments(msm)) == int(np.count_nonzero(images.camera == 0)) - 1
        assert f"version {latest.version}" in viewer.header.content
    finally:
        viewer.stop()
