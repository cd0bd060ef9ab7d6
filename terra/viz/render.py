"""`terra render`: one top-down figure of a bundle, the ones `terra eval` draws, on their own.

terrain  map points coloured by their fused terrain class
places   the places layer coloured by terrain, with its edges
regions  one panel per region level, places coloured by region
objects  the object layer's boxes (or the objects found for `queries`)
path     a terrain-aware plan (the options of `terra plan`), with its length per terrain
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from terra.errors import TerraError
from terra.fileio import writing
from terra.viz.style import Extent

if TYPE_CHECKING:
    from terra.graph.scene_graph import SceneGraph
    from terra.loaded import LoadedBundle
    from terra.mapping.semantic_map import MetricSemanticMap
    from terra.tasks.requests import PlanRequest

WHAT = ("terrain", "places", "regions", "objects", "path")


def render_bundle(
    loaded: LoadedBundle,
    what: str,
    out: str | Path,
    dpi: int = 120,
    queries: Sequence[str] = (),
    plan: PlanRequest | None = None,
) -> dict[str, Any]:
    """Draw figure `what` of the bundle into PNG `out` (replaced atomically); returns a summary.
    `queries`: objects to find for "objects"; `plan`: the plan request for "path"."""
    from terra.viz import figures
    from terra.viz.raster import point_classes, terrain_points_image

    if what not in WHAT:
        raise TerraError(f"--what {what!r}: expected one of {', '.join(WHAT)}")
    if not 20 <= dpi <= 600:
        raise TerraError(f"--dpi must be between 20 and 600, got {dpi}")
    out = Path(out)
    if out.is_dir() or not out.parent.is_dir():
        raise TerraError(f"{out}: expected a PNG file name in an existing folder")
    msm = loaded.require_map("terra render")
    graph = None if what == "terrain" else loaded.require_graph(f"--what {what}")
    background = terrain_points_image(msm.points, point_classes(msm), msm.terrain_classes, cell=msm.voxel_size)
    extent = mapped_extent(msm, loaded.graph)
    tmp = out.with_name(f".{out.name}.tmp-{os.getpid()}.png")
    summary: dict[str, Any] = {"what": what, "out": str(out)}
    try:
        with writing(out, "picture"):
            if graph is None:  # "terrain": the map alone
                figures.terrain_map_figure(
                    tmp,
                    msm.terrain_classes,
                    msm.points,
                    point_classes(msm),
                    dpi=dpi,
                    extent=extent,
                    cell=msm.voxel_size,
                )
            else:
                summary.update(_graph_figure(what, loaded, graph, tmp, background, dpi, extent, queries, plan))
            os.replace(tmp, out)
    finally:
        tmp.unlink(missing_ok=True)
    return summary


def mapped_extent(msm: MetricSemanticMap, graph: SceneGraph | None, reach: float = 20.0) -> Extent:
    """The mapped area (xmin, xmax, ymin, ymax metres): the places when there is a graph, else
    `reach` metres around the camera positions, else the 1st-99th percentile of the points; never
    every far LiDAR return, which would shrink the map to a speck."""
    from terra.viz.style import view_extent

    if graph is not None and len(graph.places):
        return view_extent(graph.places.position)
    if len(msm.images):
        cams = msm.images.position[:, :2]
        return view_extent(np.vstack([cams - reach, cams + reach]), margin=0.0)
    lo, hi = np.percentile(msm.points[:, :2], [1, 99], axis=0)
    return view_extent(np.vstack([lo, hi]))


def _graph_figure(
    what: str,
    loaded: LoadedBundle,
    graph: SceneGraph,
    tmp: Path,
    background,
    dpi: int,
    extent: Extent,
    queries: Sequence[str],
    plan: PlanRequest | None,
) -> dict[str, Any]:
    from terra.viz import figures

    if what == "places":
        figures.places_figure(tmp, graph, background, dpi, extent)
        return {"places": len(graph.places)}
    if what == "regions":
        figures.region_levels_figure(tmp, graph, background, dpi, extent)
        return {"regions_per_level": [len(level) for level in graph.regions]}
    if what == "objects":
        title = None
        if queries:
            from terra.tasks.commands import find
            from terra.tasks.requests import FindRequest
            from terra.tasks.retrieval import with_objects

            graph = with_objects(graph, find(loaded, FindRequest(queries=list(queries))).objects)
            title = "Objects for " + ", ".join(f'"{q}"' for q in queries)
        figures.objects_figure(tmp, graph, background, dpi, extent, title)
        return {"objects": len(graph.objects)}
    from terra.tasks.commands import plan as plan_path
    from terra.tasks.requests import PlanRequest

    result = plan_path(loaded, plan or PlanRequest())
    path = result.plan
    shares = ", ".join(f"{k} {v:.0f} m" for k, v in path.length_by_terrain.items())
    task = result.goal.query or f"to place {result.goal.place}"
    figures.paths_figure(
        tmp,
        graph,
        path.start,
        path.goal,
        [("plan", path.places, path.length_m)],
        task,
        background,
        dpi,
        extent,
        [shares],
    )
    return {
        "length_m": round(path.length_m, 4),
        "length_by_terrain": {k: round(v, 4) for k, v in path.length_by_terrain.items()},
        "places": len(path.places),
    }
