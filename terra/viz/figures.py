"""The evaluation report's figures, each a function writing one PNG.

Every figure is top-down in the map frame (metres). Backgrounds come from the map's points
coloured by terrain; ground truth draws in black, predictions in colour.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
from matplotlib.lines import Line2D
from matplotlib.patches import Patch, Polygon

from terra.datasets.ground_truth import GroundTruth, NamedRegion
from terra.eval.metrics.boxes import BoxSet
from terra.graph.scene_graph import SceneGraph
from terra.viz.places import draw_places, marker_size, region_colours
from terra.viz.raster import TopDownImage, terrain_raster_image
from terra.viz.style import (GOAL_COLOUR, PATH_COLOUR, START_COLOUR, Extent, new_figure, save_figure, terrain_legend,
                             topdown_axis)


def terrain_map_figure(path: str | Path, terrain_classes: list[str], map_image: TopDownImage,
                       gt: GroundTruth | None = None, dpi: int = 120, extent: Extent | None = None) -> Path:
    """Map points coloured by their fused terrain class, beside the ground-truth terrain."""
    fig, axes = new_figure(2 if gt is not None else 1, title="Terrain: metric-semantic map" + (" vs ground truth" if gt else ""), extent=extent)
    map_image.show(axes[0])
    topdown_axis(axes[0], "map points (top-down, highest point per cell)", extent)
    terrain_legend(axes[0], terrain_classes, other="not terrain")
    if gt is not None:
        terrain_raster_image(gt.terrain, terrain_classes).show(axes[1])
        topdown_axis(axes[1], "ground truth", extent)
    return save_figure(fig, path, dpi)


def places_figure(path: str | Path, sg: SceneGraph, background: TopDownImage | None = None, dpi: int = 120,
                  extent: Extent | None = None) -> Path:
    """The places layer coloured by terrain, edges grey (bridges dashed)."""
    fig, (ax,) = new_figure(1, panel_size=7.0, title=f"Places layer: {len(sg.places)} places, {len(sg.place_edges)} edges", extent=extent)
    if background is not None:
        background.show(ax, alpha=0.25)
    draw_places(ax, sg)
    topdown_axis(ax, extent=extent)
    terrain_legend(ax, sg.terrain_classes, other=None)
    return save_figure(fig, path, dpi)


def region_levels_figure(path: str | Path, sg: SceneGraph, background: TopDownImage | None = None, dpi: int = 120,
                         extent: Extent | None = None) -> Path:
    """One panel per region level: places coloured by the region containing them."""
    levels = max(len(sg.regions), 1)
    ncols = min(levels, 2)
    fig, axes = new_figure(ncols, (levels + ncols - 1) // ncols, title=f"Region levels ({sg.region_method or 'regions'})", extent=extent)
    for ax in axes[levels:]:
        ax.set_visible(False)
    if not sg.regions:
        axes[0].text(0.5, 0.5, "no region levels", ha="center", va="center", transform=axes[0].transAxes)
    for level, ax in zip(range(1, len(sg.regions) + 1), axes):
        if background is not None:
            background.show(ax, alpha=0.2)
        assignment = sg.place_region(level)
        draw_places(ax, sg, colours=region_colours(assignment, seed=level), edges=False)
        centres = sg.regions[level - 1].position
        ax.scatter(centres[:, 0], centres[:, 1], marker="x", c="black", s=25, linewidths=1.0, zorder=3)
        n = len(sg.regions[level - 1])
        topdown_axis(ax, f"level {level}: {n} region{'s' if n != 1 else ''}", extent)
    return save_figure(fig, path, dpi)


def _footprint(ax, corners: np.ndarray, **kwargs) -> None:
    ax.add_patch(Polygon(corners, closed=True, fill=False, **kwargs))


def boxes_figure(path: str | Path, gt: BoxSet, predictions: dict[str, tuple[BoxSet, np.ndarray]], queries: list[str],
                 gt_query: np.ndarray, background: TopDownImage | None = None, dpi: int = 120,
                 extent: Extent | None = None) -> Path:
    """Retrieved boxes against ground truth, one panel per method. `predictions` maps a method to
    (boxes, query index per box); `gt_query` is the query index of each ground-truth box. Ground
    truth is drawn solid and black, predictions dashed in their query's colour."""
    from matplotlib import colormaps

    colours = colormaps["tab20"](np.arange(max(len(queries), 1)) % 20)[:, :3]
    methods = list(predictions) or ["(no method)"]
    fig, axes = new_figure(len(methods), panel_size=6.0, title="Object retrieval: predicted (dashed) vs ground-truth (solid) boxes", extent=extent)
    for method, ax in zip(methods, axes):
        if background is not None:
            background.show(ax, alpha=0.3)
        for corners, q in zip(gt.footprint_corners(), gt_query):
            _footprint(ax, corners, edgecolor="black", linewidth=1.2, zorder=3)
            ax.plot(*corners.mean(axis=0), marker="o", ms=2.5, color=colours[q], zorder=4)
        boxes, query = predictions.get(method, (BoxSet.empty(), np.zeros(0, dtype=np.int64)))
        for corners, q in zip(boxes.footprint_corners(), query):
            _footprint(ax, corners, edgecolor=colours[q], linewidth=1.2, linestyle="--", zorder=5)
        topdown_axis(ax, f"{method}: {len(boxes)} boxes, {len(gt)} ground truth", extent)
    handles = [Line2D([], [], color=colours[i], linestyle="--", label=q) for i, q in enumerate(queries)]
    handles.append(Line2D([], [], color="black", label="ground truth"))
    fig.legend(handles=handles, loc="outside lower center", ncols=min(len(handles), 5), fontsize=8, frameon=False)
    return save_figure(fig, path, dpi)


def objects_figure(path: str | Path, sg: SceneGraph, background: TopDownImage | None = None, dpi: int = 120,
                   extent: Extent | None = None, title: str | None = None) -> Path:
    """The object layer: each object's footprint (its yawed box seen from above) in its label's
    colour over grey places, with a line to the place it is linked to."""
    from matplotlib import colormaps

    labels = list(dict.fromkeys(sg.objects.label))
    colours = colormaps["tab10"](np.arange(max(len(labels), 1)) % 10)[:, :3]
    fig, (ax,) = new_figure(1, panel_size=7.0, title=title or f"Objects: {len(sg.objects)} in the scene graph", extent=extent)
    if background is not None:
        background.show(ax, alpha=0.3)
    draw_places(ax, sg, colours=np.full((len(sg.places), 3), 0.7), edges=True)
    boxes = BoxSet(sg.objects.center, sg.objects.size, sg.objects.yaw)
    for corners, label, place, centre in zip(boxes.footprint_corners(), sg.objects.label, sg.objects.place, boxes.center):
        colour = colours[labels.index(label)]
        _footprint(ax, corners, edgecolor=colour, linewidth=1.8, zorder=5)
        if 0 <= place < len(sg.places):
            ax.plot([centre[0], sg.places.position[place, 0]], [centre[1], sg.places.position[place, 1]], color=colour,
                    linewidth=0.8, linestyle=":", zorder=4)
    topdown_axis(ax, extent=extent)
    if labels:
        ax.legend(handles=[Line2D([], [], color=colours[i], label=lb) for i, lb in enumerate(labels)], loc="upper right",
                  fontsize=7, framealpha=0.85)
    else:
        ax.text(0.5, 0.5, "no objects (run terra find --save, or give --query)", ha="center", va="center", transform=ax.transAxes)
    return save_figure(fig, path, dpi)


def _draw_path(ax, sg: SceneGraph, places: np.ndarray, start: int, goal: int) -> None:
    xy = sg.places.position[:, :2]
    if len(places):
        ax.plot(xy[places, 0], xy[places, 1], color=PATH_COLOUR, linewidth=2.0, zorder=4)
        ax.scatter(xy[places, 0], xy[places, 1], s=marker_size(len(sg.places)) * 1.5, c=PATH_COLOUR, edgecolors="black",
                   linewidths=0.3, zorder=5)
    ax.scatter(*xy[start], s=90, c=START_COLOUR, edgecolors="white", linewidths=1.0, zorder=6)
    ax.scatter(*xy[goal], s=90, c=GOAL_COLOUR, edgecolors="white", linewidths=1.0, zorder=6)


def paths_figure(path: str | Path, sg: SceneGraph, start: int, goal: int, plans: Sequence[tuple[str, np.ndarray, float]],
                 task: str, background: TopDownImage | None = None, dpi: int = 120, extent: Extent | None = None,
                 notes: Sequence[str] | None = None) -> Path:
    """Like the paper's navigation figure: (a) terrain-coloured places, then one panel per plan
    given as (title, place indices, length in metres), start red, goal black, path cyan.
    `notes`: one line per plan shown under its title (e.g. its terrain shares)."""
    fig, axes = new_figure(1 + len(plans), panel_size=5.5, title=f'Path planning for "{task}"', extent=extent)
    for ax in axes:
        if background is not None:
            background.show(ax, alpha=0.2)
        draw_places(ax, sg)
    topdown_axis(axes[0], "(a) terrain-coloured places", extent)
    terrain_legend(axes[0], sg.terrain_classes, other=None)
    for i, ((title, places, length), ax) in enumerate(zip(plans, axes[1:])):
        _draw_path(ax, sg, np.asarray(places, dtype=np.int64), start, goal)
        note = f"\n{notes[i]}" if notes is not None and notes[i] else ""
        topdown_axis(ax, f"({chr(ord('b') + i)}) {title}: {length:.1f} m{note}", extent)
    handles = [Line2D([], [], marker="o", linestyle="", color=START_COLOUR, label="start"),
               Line2D([], [], marker="o", linestyle="", color=GOAL_COLOUR, label="goal"),
               Line2D([], [], color=PATH_COLOUR, label="path")]
    axes[-1].legend(handles=handles, loc="upper right", fontsize=7, framealpha=0.85)
    return save_figure(fig, path, dpi)


def monitoring_figure(path: str | Path, sg: SceneGraph, regions: list[NamedRegion], predicted: list[np.ndarray],
                      method: str, background: TopDownImage | None = None, dpi: int = 120, extent: Extent | None = None) -> Path:
    """Per named region: its polygon (black) and the places predicted for its description
    (highlighted), like the paper's region-monitoring figure."""
    n = max(len(regions), 1)
    ncols = min(n, 2)
    fig, axes = new_figure(ncols, (n + ncols - 1) // ncols, title=f"Region monitoring ({method}): predicted places vs labelled regions", extent=extent)
    for ax in axes[len(regions):]:
        ax.set_visible(False)
    grey = np.full((len(sg.places), 3), 0.75)
    for region, places, ax in zip(regions, predicted, axes):
        if background is not None:
            background.show(ax, alpha=0.25)
        draw_places(ax, sg, colours=grey, edges=False)
        xy = sg.places.position[np.asarray(places, dtype=np.int64)]
        ax.scatter(xy[:, 0], xy[:, 1], s=marker_size(len(sg.places)) * 1.5, c="#ff7f0e", edgecolors="black", linewidths=0.3, zorder=4)
        ax.add_patch(Polygon(region.polygon, closed=True, fill=False, edgecolor="black", linewidth=1.5, zorder=5))
        topdown_axis(ax, f'"{region.description}"' if len(region.description) < 60 else region.name, extent)
    axes[0].legend(handles=[Patch(color="#ff7f0e", label="predicted places"), Line2D([], [], color="black", label="labelled region")],
                   loc="upper right", fontsize=7, framealpha=0.85)
    return save_figure(fig, path, dpi)


def memory_figure(path: str | Path, entries: Sequence[tuple[str, dict[str, int], float]], dpi: int = 120) -> Path:
    """Stacked bars of bundle bytes by component (MiB) per entry (label, component bytes, area m^2),
    annotated with bytes per square metre of mapped area, like the paper's memory figure."""
    from matplotlib import colormaps

    components = sorted({c for _, comp, _ in entries for c in comp})
    colours = colormaps["Set2"](np.arange(max(len(components), 1)) % 8)
    fig, (ax,) = new_figure(1, panel_size=4.5, title="Saved map and graph size")
    x = np.arange(len(entries))
    bottom = np.zeros(len(entries))
    for c, colour in zip(components, colours):
        mib = np.array([comp.get(c, 0) / 2**20 for _, comp, _ in entries])
        ax.bar(x, mib, bottom=bottom, color=colour, label=c, width=0.6)
        bottom += mib
    for xi, (label, comp, area) in zip(x, entries):
        total = sum(comp.values())
        ax.annotate(f"{total / 2**20:.2f} MiB\n{area:,.0f} m²\n{total / max(area, 1e-9):,.0f} B/m²", (xi, bottom[xi]),
                    ha="center", va="bottom", fontsize=7, xytext=(0, 2), textcoords="offset points")
    ax.set_xticks(x, [label for label, _, _ in entries], fontsize=8)
    ax.set_xlim(-0.5 - 0.5 / max(len(entries), 1), len(entries) - 0.5 + 0.5 / max(len(entries), 1))
    ax.set_ylabel("MiB on disk", fontsize=8)
    ax.set_ylim(0, max(bottom.max(initial=0) * 1.35, 1e-3))
    ax.legend(fontsize=7, loc="upper left")
    return save_figure(fig, path, dpi)
