"""`terra render`: one top-down figure of a bundle, the ones `terra eval` draws, on their own.

terrain  map points coloured by their fused terrain class
places   the places layer coloured by terrain, with its edges
regions  one panel per region level, places coloured by region
objects  the object layer's boxes (or the objects found for `queries`)
path     a terrain-aware plan (the options of `terra plan`), with its length per terrain
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from terra.bundle import Bundle
from terra.errors import TerraError

WHAT = ("terrain", "places", "regions", "objects", "path")


def render_bundle(bundle: str | Path, what: str, out: str | Path, dpi: int = 120, queries: Sequence[str] = (),
                  plan: dict[str, Any] | None = None) -> dict[str, Any]:
    """Draw figure `what` of `bundle` into PNG `out` (replaced atomically); returns a summary.
    `queries`: objects to find for "objects"; `plan`: keyword arguments of `plan_report` for "path"."""
    from terra.viz import figures
    from terra.viz.raster import terrain_points_image

    if what not in WHAT:
        raise TerraError(f"--what {what!r}: expected one of {', '.join(WHAT)}")
    if not 20 <= dpi <= 600:
        raise TerraError(f"--dpi must be between 20 and 600, got {dpi}")
    out = Path(out)
    if out.is_dir() or not out.parent.is_dir():
        raise TerraError(f"{out}: expected a PNG file name in an existing folder")
    source = Bundle(bundle)
    from terra.mapping.storage import load_map

    msm = load_map(source)
    background = terrain_points_image(msm.points, msm.terrain_index(), msm.terrain_classes, cell=msm.voxel_size)
    tmp = out.with_name(f".{out.name}.tmp-{os.getpid()}.png")
    summary: dict[str, Any] = {"what": what, "out": str(out)}
    try:
        if what == "terrain":
            figures.terrain_map_figure(tmp, msm.terrain_classes, background, dpi=dpi, extent=mapped_extent(msm, source))
        else:
            from terra.graph.storage import load_scene_graph

            graph = load_scene_graph(source)
            extent = mapped_extent(msm, source)
            summary.update(_graph_figure(what, source, graph, tmp, background, dpi, extent, queries, plan or {}))
        os.replace(tmp, out)
    finally:
        tmp.unlink(missing_ok=True)
    return summary


def mapped_extent(msm, source: Bundle, reach: float = 20.0):
    """The mapped area (xmin, xmax, ymin, ymax metres): the places when the bundle has a graph,
    else `reach` metres around the camera positions, else the 1st-99th percentile of the points;
    never every far LiDAR return, which would shrink the map to a speck."""
    from terra.tasks.context import has_component
    from terra.viz.style import view_extent

    if has_component(source, "graph"):
        from terra.graph.storage import load_scene_graph

        places = load_scene_graph(source).places.position
        if len(places):
            return view_extent(places)
    if len(msm.images):
        cams = msm.images.position[:, :2]
        return view_extent(np.vstack([cams - reach, cams + reach]), margin=0.0)
    lo, hi = np.percentile(msm.points[:, :2], [1, 99], axis=0)
    return view_extent(np.vstack([lo, hi]))


def _graph_figure(what: str, source: Bundle, graph, tmp: Path, background, dpi: int, extent, queries: Sequence[str],
                  plan: dict[str, Any]) -> dict[str, Any]:
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
            graph = _with_found_objects(source, graph, queries)
            title = "Objects for " + ", ".join(f'"{q}"' for q in queries)
        figures.objects_figure(tmp, graph, background, dpi, extent, title)
        return {"objects": len(graph.objects)}
    from terra.tasks.commands import plan_report

    report = plan_report(source.path, **plan)
    shares = ", ".join(f"{k} {v:.0f} m" for k, v in report["length_by_terrain"].items())
    task = report["goal"]["query"] or f"to place {report['goal']['place']}"
    figures.paths_figure(tmp, graph, report["start_place"], report["goal_place"],
                         [("plan", np.asarray(report["places"]), report["length_m"])], task, background, dpi, extent, [shares])
    return {"length_m": report["length_m"], "length_by_terrain": report["length_by_terrain"], "places": len(report["places"])}


def _with_found_objects(source: Bundle, graph, queries: Sequence[str]):
    """`graph` with the objects `terra find` returns for `queries` (default method and alpha)."""
    from terra.tasks.config import TasksConfig, alpha_for
    from terra.tasks.context import open_for_tasks
    from terra.tasks.queries import clean_queries
    from terra.tasks.retrieval import find_objects, with_objects

    config = TasksConfig()
    ctx = open_for_tasks(source.path, config, need_map=True, need_graph=True)
    alpha = alpha_for(config.retrieval.alpha, config.retrieval.default_alpha, ctx.embedder.name)
    found = find_objects(ctx.msm, graph, clean_queries(list(queries)), method=config.retrieval.method, alpha=alpha, config=config,
                         embedder=ctx.embedder)
    return with_objects(graph, found)
