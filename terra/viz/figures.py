"""The evaluation report's figures, each a function writing one PNG.

Every map figure is top-down in the map frame (metres), in one terrain palette (terra.viz.style,
the same as the simulator's world.png); backgrounds are the map's points coloured by terrain,
faded. Overlays use colours that are no terrain's: ground truth black, paths magenta, predicted
places orange, methods METHOD_COLOURS. Legends sit below the panels, never over data. The
retrieval figure, with its zoomed insets, is in terra.viz.retrieval_figure.
"""

from __future__ import annotations

import textwrap
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.lines import Line2D
from matplotlib.patches import Patch, Polygon

from terra.datasets.ground_truth import GroundTruth, NamedRegion
from terra.graph.scene_graph import SceneGraph
from terra.tasks.boxes import BoxSet
from terra.viz.class_grid import (
    DIFFERENCE_COLOURS,
    DIFFERENCE_LABELS,
    difference,
    difference_rgba,
    gt_class_grid,
    map_class_grid,
)
from terra.viz.places import (
    adjacent_region_colours,
    draw_place_edges,
    draw_places,
    edge_handles,
    extent_with_places,
    marker_size,
)
from terra.viz.raster import TopDownImage
from terra.viz.retrieval_figure import boxes_figure  # noqa: F401 (one module of figures for callers)
from terra.viz.style import (
    GOAL_COLOUR,
    HIGHLIGHT_COLOUR,
    PATH_COLOUR,
    START_COLOUR,
    UNSEEN_COLOUR,
    Extent,
    figure_legend,
    new_figure,
    save_figure,
    terrain_handles,
    topdown_axis,
    view_extent,
)
from terra.words import counted


def _outline_buildings(ax, gt: GroundTruth | None) -> None:
    """Ground-truth building footprints as thin outlines, the same on every panel."""
    if gt is None:
        return
    buildings = [o for o in gt.objects if o.class_name == "building"]
    for corners in BoxSet.from_objects(buildings).footprint_corners() if buildings else []:
        ax.add_patch(Polygon(corners, closed=True, fill=False, edgecolor="black", linewidth=0.8, zorder=4))


def terrain_map_figure(
    path: str | Path,
    terrain_classes: list[str],
    points: np.ndarray,
    terrain_index: np.ndarray,
    gt: GroundTruth | None = None,
    dpi: int = 120,
    extent: Extent | None = None,
    cell: float = 0.4,
) -> Path:
    """(a) the map's points by class (`terrain_index`: terra.viz.raster.point_classes) and (b) the
    ground truth (terrain raster with every object's footprint as not terrain), both on the same
    `cell` grid and drawn the same way, and (c) where they differ. Without `gt`, the map panel alone."""
    extent = extent or view_extent(points)
    map_grid = map_class_grid(points, terrain_index, len(terrain_classes), extent, cell)
    truth = gt if gt is not None and gt.terrain is not None else None
    panels = 3 if truth is not None else 1
    fig, axes = new_figure(
        panels,
        panel_size=5.5,
        extent=extent,
        title="Terrain: the map" + (" against the ground truth" if panels == 3 else ""),
    )
    axes[0].imshow(map_grid.rgba(terrain_classes), origin="lower", extent=map_grid.extent, interpolation="nearest")
    topdown_axis(axes[0], "(a) map: highest point per cell" if panels == 3 else "map: highest point per cell", extent)
    handles = terrain_handles(terrain_classes, "not terrain")
    handles.append(Patch(color=UNSEEN_COLOUR, label="no camera label (LiDAR only)"))
    if truth is not None:
        gt_grid = gt_class_grid(truth, terrain_classes, map_grid.extent, cell)
        axes[1].imshow(gt_grid.rgba(terrain_classes), origin="lower", extent=gt_grid.extent, interpolation="nearest")
        topdown_axis(axes[1], "(b) ground truth: terrain, objects on top", extent)
        categories, share = difference(map_grid, gt_grid)
        axes[2].imshow(difference_rgba(categories), origin="lower", extent=gt_grid.extent, interpolation="nearest")
        agree = "" if share is None else f": terrain agrees on {100 * share:.1f}% of cells"
        topdown_axis(axes[2], f"(c) difference{agree}", extent)
        for ax in axes:
            _outline_buildings(ax, gt)
        handles += [Patch(color=c, label=label) for c, label in zip(DIFFERENCE_COLOURS, DIFFERENCE_LABELS)]
        handles.append(Line2D([], [], color="black", linewidth=0.8, label="building outline (ground truth)"))
    figure_legend(fig, handles, ncols=min(len(handles), 5))
    return save_figure(fig, path, dpi)


def places_figure(
    path: str | Path,
    sg: SceneGraph,
    background: TopDownImage | None = None,
    dpi: int = 120,
    extent: Extent | None = None,
) -> Path:
    """The places layer coloured by terrain; edges along one terrain grey, cross-terrain links
    black, bridges dashed. The view is `extent` grown to hold every place."""
    extent = extent_with_places(extent, sg)
    fig, (ax,) = new_figure(
        1,
        panel_size=7.5,
        extent=extent,
        title=f"Places layer: {counted(len(sg.places), 'place')}, {counted(len(sg.place_edges), 'edge')}",
    )
    if background is not None:
        background.show(ax, alpha=0.25)
    counts = draw_place_edges(ax, sg)
    draw_places(ax, sg, edges=False, zorder=3)
    topdown_axis(ax, extent=extent)
    figure_legend(fig, terrain_handles(sg.terrain_classes, None) + edge_handles(counts), ncols=4)
    return save_figure(fig, path, dpi)


def region_levels_figure(
    path: str | Path,
    sg: SceneGraph,
    background: TopDownImage | None = None,
    dpi: int = 120,
    extent: Extent | None = None,
) -> Path:
    """One panel per region level: places coloured by the region containing them, region
    centres as crosses."""
    levels = max(len(sg.regions), 1)
    ncols = min(levels, 2)
    fig, axes = new_figure(
        ncols,
        (levels + ncols - 1) // ncols,
        extent=extent,
        title=f"Region levels ({sg.region_method or 'regions'}): places by region, x = region centre",
    )
    for ax in axes[levels:]:
        ax.set_visible(False)
    if not sg.regions:
        axes[0].text(0.5, 0.5, "no region levels", ha="center", va="center", transform=axes[0].transAxes)
    for level, ax in zip(range(1, len(sg.regions) + 1), axes):
        if background is not None:
            background.show(ax, alpha=0.2)
        assignment = sg.place_region(level)
        draw_places(ax, sg, colours=adjacent_region_colours(sg, assignment), edges=False)
        centres = sg.regions[level - 1].position
        ax.scatter(centres[:, 0], centres[:, 1], marker="x", c="black", s=25, linewidths=1.0, zorder=3)
        topdown_axis(ax, f"level {level}: {counted(len(sg.regions[level - 1]), 'region')}", extent)
    return save_figure(fig, path, dpi)


def _footprint(ax, corners: np.ndarray, **kwargs) -> None:
    ax.add_patch(Polygon(corners, closed=True, fill=False, **kwargs))


def objects_figure(
    path: str | Path,
    sg: SceneGraph,
    background: TopDownImage | None = None,
    dpi: int = 120,
    extent: Extent | None = None,
    title: str | None = None,
) -> Path:
    """The object layer: each object's footprint (its yawed box seen from above) in its label's
    colour over grey places, with a line to the place it is linked to."""
    from matplotlib import colormaps

    labels = list(dict.fromkeys(sg.objects.label))
    colours = colormaps["tab10"](np.arange(max(len(labels), 1)) % 10)[:, :3]
    title = title or f"Objects: {counted(len(sg.objects), 'object')} in the scene graph"
    fig, (ax,) = new_figure(1, panel_size=7.0, title=title, extent=extent)
    if background is not None:
        background.show(ax, alpha=0.3)
    draw_places(ax, sg, colours=np.full((len(sg.places), 3), 0.7), edges="#b0b0b0")
    boxes = BoxSet(sg.objects.center, sg.objects.size, sg.objects.yaw)
    for corners, label, place, centre in zip(
        boxes.footprint_corners(), sg.objects.label, sg.objects.place, boxes.center
    ):
        colour = colours[labels.index(label)]
        _footprint(ax, corners, edgecolor=colour, linewidth=1.8, zorder=5)
        if 0 <= place < len(sg.places):
            ax.plot(
                [centre[0], sg.places.position[place, 0]],
                [centre[1], sg.places.position[place, 1]],
                color=colour,
                linewidth=0.8,
                linestyle=":",
                zorder=4,
            )
    topdown_axis(ax, extent=extent)
    if labels:
        figure_legend(fig, [Line2D([], [], color=colours[i], label=lb) for i, lb in enumerate(labels)], ncols=3)
    else:
        ax.text(
            0.5,
            0.5,
            "no objects (run terra find --save, or give --query)",
            ha="center",
            va="center",
            transform=ax.transAxes,
        )
    return save_figure(fig, path, dpi)


def _draw_path(ax, sg: SceneGraph, places: np.ndarray, start: int, goal: int) -> None:
    xy = sg.places.position[:, :2]
    if len(places):
        ax.plot(xy[places, 0], xy[places, 1], color="white", linewidth=4.0, zorder=4, solid_capstyle="round")
        ax.plot(xy[places, 0], xy[places, 1], color=PATH_COLOUR, linewidth=2.2, zorder=4.5, solid_capstyle="round")
    ax.scatter(*xy[start], s=110, c=START_COLOUR, edgecolors="black", linewidths=1.5, zorder=6)
    ax.scatter(*xy[goal], s=170, marker="*", c=GOAL_COLOUR, edgecolors="white", linewidths=1.0, zorder=6)


@dataclass(frozen=True)
class PathCase:
    """One row of the navigation figure: plans from `start` to `goal` (place indices), each
    (title, place indices, length in metres), with one note per plan (e.g. its terrain shares)
    and the heading of the row's first panel."""

    heading: str
    start: int
    goal: int
    plans: Sequence[tuple[str, np.ndarray, float]]
    notes: Sequence[str] | None = None


def paths_figure(
    path: str | Path,
    sg: SceneGraph,
    start: int,
    goal: int,
    plans: Sequence[tuple[str, np.ndarray, float]],
    task: str,
    background: TopDownImage | None = None,
    dpi: int = 120,
    extent: Extent | None = None,
    notes: Sequence[str] | None = None,
    case: PathCase | None = None,
) -> Path:
    """Like the paper's navigation figure: (a) terrain-coloured places, then one panel per plan
    given as (title, place indices, length in metres); the path magenta, the start a white disc,
    the goal a black star (no terrain has these colours). `notes`: one line per plan shown under
    its title (e.g. its terrain shares). `case`: a second row the same way (e.g. the pair of
    places where the preference changes the path, when the task's plans coincide)."""
    rows = [PathCase("terrain-coloured places", start, goal, plans, notes)] + ([case] if case is not None else [])
    ncols = 1 + max(len(r.plans) for r in rows)
    fig, axes = new_figure(ncols, len(rows), panel_size=5.5, title=f'Path planning for "{task}"', extent=extent)
    for r, row in enumerate(rows):
        _path_row(axes[r * ncols : (r + 1) * ncols], sg, row, background, extent, r * ncols)
    handles = terrain_handles(sg.terrain_classes, None) + [
        Line2D([], [], marker="o", linestyle="", markerfacecolor=START_COLOUR, markeredgecolor="black", label="start"),
        Line2D([], [], marker="*", linestyle="", markersize=10, color=GOAL_COLOUR, label="goal"),
        Line2D([], [], color=PATH_COLOUR, linewidth=2.2, label="path"),
    ]
    figure_legend(fig, handles, ncols=len(handles))
    return save_figure(fig, path, dpi)


def _path_row(
    axes: list[Axes], sg: SceneGraph, row: PathCase, background: TopDownImage | None, extent: Extent | None, first: int
) -> None:
    """One row: the places with the row's start and goal, then a panel per plan, lettered from
    the `first` panel's letter on."""
    for ax in axes:
        if background is not None:
            background.show(ax, alpha=0.2)
        draw_places(ax, sg, edges="#a0a0a0")
    for ax in axes[1 + len(row.plans) :]:
        ax.set_visible(False)
    if first:  # rows after the first mark where their plans start and end
        _draw_path(axes[0], sg, np.zeros(0, dtype=np.int64), row.start, row.goal)
    topdown_axis(axes[0], f"({chr(ord('a') + first)}) {row.heading}", extent)
    for i, ((title, places, length), ax) in enumerate(zip(row.plans, axes[1:])):
        _draw_path(ax, sg, np.asarray(places, dtype=np.int64), row.start, row.goal)
        note = f"\n{row.notes[i]}" if row.notes is not None and row.notes[i] else ""
        topdown_axis(ax, f"({chr(ord('a') + first + 1 + i)}) {title}: {length:.1f} m{note}", extent)


def monitoring_figure(
    path: str | Path,
    sg: SceneGraph,
    regions: list[NamedRegion],
    predicted: list[np.ndarray],
    method: str,
    background: TopDownImage | None = None,
    dpi: int = 120,
    extent: Extent | None = None,
    scores: Sequence[tuple[float, float]] | None = None,
    parameters: dict | None = None,
) -> Path:
    """Per labelled region, a panel titled with its query (the region's description) and, given
    `scores` [(precision, recall)], how well it was answered: the region's polygon (black), its
    places (black rings) and the places predicted for the query (orange). `parameters` (k,
    alpha, ...) are named in the title beside the method."""
    n = max(len(regions), 1)
    ncols = min(n, min((3, 4), key=lambda c: (-(-n // c) * c - n, c)))  # 3 or 4 columns, fewest empty panels
    fig, axes = new_figure(
        ncols,
        (n + ncols - 1) // ncols,
        panel_size=4.6,
        extent=extent,
        title=f"Region monitoring ({_with_parameters(method, parameters)}): the places predicted for each region's "
        "description",
    )
    for ax in axes[len(regions) :]:
        ax.set_visible(False)
    for i, (region, places, ax) in enumerate(zip(regions, predicted, axes)):
        _monitoring_panel(ax, sg, region, places, background, extent, None if scores is None else scores[i])
    figure_legend(
        fig,
        [
            Patch(color=HIGHLIGHT_COLOUR, label="predicted places"),
            Line2D(
                [],
                [],
                marker="o",
                linestyle="",
                markerfacecolor="none",
                markeredgecolor="black",
                label="places in the region",
            ),
            Line2D([], [], color="black", label="labelled region"),
        ],
        ncols=3,
    )
    return save_figure(fig, path, dpi)


def _with_parameters(method: str, parameters: dict | None) -> str:
    """'agglomerative, k 5, alpha 0.65' (the method alone without parameters)."""
    words = [f"{k} {v:g}" if isinstance(v, float) else f"{k} {v}" for k, v in (parameters or {}).items()]
    return ", ".join([method, *words])


def _monitoring_panel(
    ax: Axes,
    sg: SceneGraph,
    region: NamedRegion,
    places: np.ndarray,
    background: TopDownImage | None,
    extent: Extent | None,
    score: tuple[float, float] | None,
) -> None:
    """One region's panel: every place in grey, the region's places ringed, the predicted ones
    highlighted, the polygon, and a title with its description and (precision, recall)."""
    from terra.tasks.monitoring import places_in_polygon

    grey = np.full((len(sg.places), 3), 0.78)
    size = marker_size(len(sg.places))
    if background is not None:
        background.show(ax, alpha=0.2)
    draw_places(ax, sg, colours=grey, edges=False)
    truth = sg.places.position[places_in_polygon(sg.places.position, region.polygon)]
    ax.scatter(truth[:, 0], truth[:, 1], s=size * 2.2, facecolors="none", edgecolors="black", linewidths=0.8, zorder=4)
    xy = sg.places.position[np.asarray(places, dtype=np.int64)]
    ax.scatter(xy[:, 0], xy[:, 1], s=size * 1.4, c=HIGHLIGHT_COLOUR, edgecolors="black", linewidths=0.3, zorder=5)
    ax.add_patch(Polygon(region.polygon, closed=True, fill=False, edgecolor="black", linewidth=1.5, zorder=6))
    title = "\n".join(textwrap.wrap(f'"{region.description}"', 44))
    if score is not None:
        p, r = score
        title += f"\nP {p:.2f}, R {r:.2f} ({counted(len(xy), 'place')} predicted, {len(truth)} in the region)"
    topdown_axis(ax, title, extent)
    ax.title.set_fontsize(8.5)


def memory_figure(path: str | Path, parts: dict[str, int], area_m2: float, label: str = "", dpi: int = 120) -> Path:
    """What the saved map and graph spend their bytes on: one bar per part (MiB), annotated with
    bytes per square metre of mapped area and the share of the total (map parts purple, graph
    parts orange)."""
    names = sorted(parts, key=lambda n: (-parts[n], n))  # largest first (summary.json sorts keys by name)
    mib = np.array([parts[n] / 2**20 for n in names])
    total = max(sum(parts.values()), 1)
    per_m2 = total / max(area_m2, 1e-9)
    title = (
        f"Saved map and graph{' of ' + label if label else ''}: {total / 2**20:.2f} MiB for {area_m2:,.0f} m² "
        f"({per_m2:,.0f} B/m²)"
    )
    fig, (ax,) = new_figure(1, panel_size=7.5, title=title)
    fig.set_size_inches(7.5, max(0.42 * len(names) + 1.2, 3.0))
    y = np.arange(len(names))[::-1]
    colours = [
        "#6a3d9a" if n.startswith("map") else HIGHLIGHT_COLOUR if n.startswith("graph") else "#9e9e9e" for n in names
    ]
    ax.barh(y, mib, color=colours, height=0.65)
    for yi, name, value in zip(y, names, mib):
        ax.annotate(
            f"{parts[name] / max(area_m2, 1e-9):,.1f} B/m², {100 * parts[name] / total:.0f}%",
            (value, yi),
            xytext=(4, 0),
            textcoords="offset points",
            va="center",
            fontsize=8,
        )
    ax.set_yticks(y, names, fontsize=8)
    ax.set_xlabel("MiB on disk", fontsize=8)
    ax.set_xlim(0, max(float(mib.max(initial=0)) * 1.45, 1e-3))
    ax.tick_params(axis="x", labelsize=7)
    for side in ("top", "right"):
        ax.spines[side].set_visible(False)
    return save_figure(fig, path, dpi)
