"""Top-down picture of a simulated world: terrain colours, buildings, trees, objects, the robot's
route, named regions, a scale bar and a legend. Same input, same PNG bytes (Agg, no metadata)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from terra.datasets.ground_truth import GroundTruth, TerrainRaster
from terra.errors import TerraError

if TYPE_CHECKING:  # matplotlib is imported when a picture is drawn
    from matplotlib.artist import Artist
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

_ROUTE = "#ff00ff"
_DETAILED_BELOW_M = 800.0  # larger worlds: thinner lines and no region names (they would overlap)


def scale_bar_length(extent_m: float) -> float:
    """A round length (1, 2 or 5 times a power of ten, metres) near a fifth of `extent_m`."""
    target = max(extent_m, 1e-9) / 5.0
    power = 10.0 ** np.floor(np.log10(target))
    return float(max((m * power for m in (1.0, 2.0, 5.0) if m * power <= target), default=power))


def _box_corners(center: np.ndarray, size: np.ndarray, yaw: float) -> np.ndarray:
    """(4, 2) corners in the map frame of a box (centre and size in metres, yaw in radians about +z)."""
    c, s = np.cos(yaw), np.sin(yaw)
    hx, hy = size[0] / 2, size[1] / 2
    return np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]]) @ np.array([[c, s], [-s, c]]) + center[:2]


def world_colours(gt: GroundTruth, colors: np.ndarray) -> np.ndarray:
    """RGB 0..255 per class id: terrain, buildings and trees as every report figure draws them
    (terra.viz.style's palette); the simulator's own colours (its camera images') for the rest."""
    from matplotlib.colors import to_rgb

    from terra.viz.style import OTHER_COLOUR, TREE_COLOUR, terrain_colour

    out = np.array(colors, dtype=np.float64).copy()
    for class_id, name in gt.terrain.legend.items() if gt.terrain is not None else ():
        if 0 < class_id < len(out) and name != "unlabeled":
            out[class_id] = np.asarray(terrain_colour(name, class_id)) * 255.0
    for o in gt.objects:
        if o.class_name in ("building", "tree") and 0 <= o.class_id < len(out):
            out[o.class_id] = np.asarray(to_rgb(OTHER_COLOUR if o.class_name == "building" else TREE_COLOUR)) * 255.0
    return out


def render_world_png(
    gt: GroundTruth,
    out: str | Path,
    trajectory_xy: np.ndarray | None = None,
    colors: np.ndarray | None = None,
    title: str = "",
    dpi: int = 110,
) -> Path:
    """Write a top-down PNG (map frame, x right, y up, metres) of `gt` and the robot trajectory.

    trajectory_xy: (M, 2) robot positions in the map frame, metres. colors: RGB uint8 per class id
    (defaults to the simulator's). Returns the path written.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    raster = gt.terrain
    if raster is None:
        raise TerraError("the world picture needs the ground truth's terrain raster; this one has none")
    if colors is None:
        from terra.sim.classes import CLASS_COLORS as colors
    palette = world_colours(gt, colors)
    h, w = raster.classes.shape
    x0, y0 = raster.origin
    bounds = (x0, x0 + w * raster.resolution, y0, y0 + h * raster.resolution)
    x1, y1 = bounds[1], bounds[3]
    detailed = max(x1 - x0, y1 - y0) < _DETAILED_BELOW_M

    side = 8.0
    fig = plt.figure(figsize=(side + 3.2, side * (y1 - y0) / max(x1 - x0, 1e-9) + 0.7))
    ax = fig.add_axes((0.07, 0.06, side / (side + 3.2) * 0.93, 0.88))
    ax.imshow(
        palette[np.clip(raster.classes, 0, len(palette) - 1)].astype(np.uint8),
        origin="lower",
        extent=bounds,
        interpolation="nearest",
    )
    _draw_objects(ax, gt, palette, detailed)
    if trajectory_xy is not None and len(trajectory_xy):
        _draw_route(ax, np.asarray(trajectory_xy), detailed)
    _draw_regions(ax, gt, detailed)
    _draw_scale_bar(ax, bounds)
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    if title:
        ax.set_title(title, fontsize=10)
    _world_legend(fig, raster, gt, palette, side)
    out = Path(out)
    fig.savefig(out, dpi=dpi, metadata={"Software": None}, bbox_inches="tight", pad_inches=0.1)
    plt.close(fig)
    return out


def _class_rgb(palette: np.ndarray, class_id: int) -> tuple[float, float, float]:
    """A class's colour, 0..1 (grey for an id beyond the palette)."""
    if not 0 <= class_id < len(palette):
        return (0.5, 0.5, 0.5)
    r, g, b = palette[class_id] / 255.0
    return (r, g, b)


def _draw_objects(ax: Axes, gt: GroundTruth, palette: np.ndarray, detailed: bool) -> None:
    """Objects, lowest first so tall things (buildings, trees) stay on top; trees as crowns."""
    from matplotlib.collections import PatchCollection
    from matplotlib.patches import Circle, Patch, Polygon

    patches: list[Patch] = []
    faces, edges = [], []
    for o in sorted(gt.objects, key=lambda o: (o.center[2] + o.size[2] / 2, o.instance_id)):
        if o.class_name == "tree":
            patches.append(Circle((o.center[0], o.center[1]), max(o.size[0], o.size[1]) / 2))
            faces.append((*_class_rgb(palette, o.class_id), 0.6))
            edges.append((0, 0, 0, 0))
        else:
            patches.append(Polygon(_box_corners(o.center, o.size, o.yaw), closed=True))
            faces.append((*_class_rgb(palette, o.class_id), 1.0))
            edges.append((0, 0, 0, 1) if o.class_name in ("building", "car") else (0, 0, 0, 0.6))
    ax.add_collection(
        PatchCollection(patches, facecolors=faces, edgecolors=edges, linewidths=0.35 if detailed else 0.1)
    )


def _draw_route(ax: Axes, trajectory_xy: np.ndarray, detailed: bool) -> None:
    """The robot's route (M, 2), a circle at its start, a square at its end, an arrow leaving the start."""
    ax.plot(trajectory_xy[:, 0], trajectory_xy[:, 1], color=_ROUTE, lw=1.4 if detailed else 0.6, zorder=3)
    ax.plot(*trajectory_xy[0, :2], marker="o", color=_ROUTE, mec="k", ms=7, zorder=4)
    ax.plot(*trajectory_xy[-1, :2], marker="s", color=_ROUTE, mec="k", ms=6, zorder=4)
    if len(trajectory_xy) > 1:  # direction of travel at the start
        step = min(len(trajectory_xy) - 1, 3)
        ax.annotate(
            "",
            xy=(trajectory_xy[step, 0], trajectory_xy[step, 1]),
            xytext=(trajectory_xy[0, 0], trajectory_xy[0, 1]),
            zorder=4,
            arrowprops={"arrowstyle": "-|>", "color": _ROUTE, "lw": 1.5, "mutation_scale": 14},
        )


def _draw_regions(ax: Axes, gt: GroundTruth, detailed: bool) -> None:
    """Named regions as dashed white outlines, named at their centre when the world is small enough."""
    from matplotlib.patches import Polygon

    for r in gt.regions:
        poly = np.asarray(r.polygon)
        ax.add_patch(
            Polygon(poly, closed=True, fill=False, edgecolor="white", lw=1.1 if detailed else 0.5, ls="--", zorder=5)
        )
        if detailed:
            cx, cy = poly.mean(axis=0)
            ax.text(
                cx,
                cy,
                r.name,
                color="white",
                fontsize=6.5,
                ha="center",
                va="center",
                zorder=6,
                bbox={"facecolor": "black", "alpha": 0.55, "pad": 1.2, "lw": 0},
            )


def _draw_scale_bar(ax: Axes, bounds: tuple[float, float, float, float]) -> None:
    """Scale bar in the lower-left corner, on a white backing so it reads on any terrain."""
    from matplotlib.patches import Rectangle

    x0, x1, y0, y1 = bounds
    big = max(x1 - x0, y1 - y0)
    length = scale_bar_length(x1 - x0)
    bx, by = x0 + 0.03 * (x1 - x0), y0 + 0.03 * (y1 - y0)
    ax.add_patch(
        Rectangle(
            (bx - 0.01 * big, by - 0.012 * big),
            length + 0.02 * big,
            0.05 * big,
            facecolor="white",
            alpha=0.85,
            lw=0,
            zorder=6,
        )
    )
    ax.plot([bx, bx + length], [by, by], color="black", lw=3, solid_capstyle="butt", zorder=7)
    ax.text(bx + length / 2, by + 0.012 * big, f"{length:g} m", ha="center", va="bottom", fontsize=8, zorder=7)


def _world_legend(fig: Figure, raster: TerrainRaster, gt: GroundTruth, palette: np.ndarray, side: float) -> None:
    """Legend: terrain present in the raster, then structures and objects present in the world."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    terrain_ids = [int(i) for i in np.unique(raster.classes) if int(i) in raster.legend]
    object_ids = sorted({(o.class_id, o.class_name) for o in gt.objects})
    handles: list[Artist] = [
        Patch(facecolor=_class_rgb(palette, i), edgecolor="0.3", lw=0.4, label=raster.legend[i]) for i in terrain_ids
    ]
    handles += [Patch(facecolor=_class_rgb(palette, i), edgecolor="0.3", lw=0.4, label=name) for i, name in object_ids]
    handles += [
        Line2D([], [], color=_ROUTE, lw=1.5, marker="o", mec="k", label="route (o start, \u25a1 end)"),
        Line2D([], [], color="0.4", lw=1.1, ls="--", label="named region"),
    ]
    fig.legend(
        handles=handles,
        loc="upper left",
        bbox_to_anchor=(side / (side + 3.2) * 0.93 + 0.08, 0.94),
        fontsize=7.5,
        frameon=False,
        title=f"terrain ({len(terrain_ids)}), objects ({len(object_ids)})",
        title_fontsize=8,
        handlelength=1.6,
        labelspacing=0.35,
        ncols=1 if len(handles) <= 36 else 2,
    )
