"""Drawing the places layer: nodes coloured by terrain or by region, edges as thin lines."""

from __future__ import annotations

import numpy as np
from matplotlib.axes import Axes
from matplotlib.collections import LineCollection

from terra.graph.scene_graph import EDGE_BRIDGE, SceneGraph
from terra.viz.style import terrain_palette


def marker_size(count: int) -> float:
    """Scatter marker area (points^2) that stays readable from ten to ten thousand nodes."""
    return float(np.clip(4000.0 / max(count, 1), 3.0, 30.0))


def draw_place_edges(ax: Axes, sg: SceneGraph, colour: str = "#7f7f7f", width: float = 0.6, alpha: float = 0.7) -> None:
    """Place edges as line segments; bridge edges (joining components) dashed."""
    if len(sg.place_edges) == 0:
        return
    xy = sg.places.position[:, :2]
    bridge = sg.place_edge_kind == EDGE_BRIDGE
    for mask, style in ((~bridge, "solid"), (bridge, "dashed")):
        if mask.any():
            segs = xy[sg.place_edges[mask]]
            ax.add_collection(LineCollection(segs, colors=colour, linewidths=width, alpha=alpha, linestyles=style, zorder=1))


def draw_places(ax: Axes, sg: SceneGraph, colours: np.ndarray | None = None, edges: bool = True,
                size: float | None = None, zorder: int = 2) -> None:
    """Place nodes at their map-frame xy, coloured by terrain unless `colours` (P, 3) is given."""
    if edges:
        draw_place_edges(ax, sg)
    if len(sg.places) == 0:
        return
    if colours is None:
        colours = terrain_palette(sg.terrain_classes)[sg.places.terrain]
    xy = sg.places.position
    ax.scatter(xy[:, 0], xy[:, 1], s=size or marker_size(len(sg.places)), c=colours, edgecolors="black",
               linewidths=0.2, zorder=zorder)
    ax.autoscale_view()


def region_colours(assignment: np.ndarray, seed: int = 0) -> np.ndarray:
    """(P, 3) distinct-looking colours per region id: a fixed shuffle of a qualitative palette so
    neighbouring region ids (often neighbouring regions) do not share a hue."""
    from matplotlib import colormaps

    base = np.vstack([colormaps["tab20"](np.arange(20))[:, :3], colormaps["tab20b"](np.arange(20))[:, :3]])
    n = int(assignment.max()) + 1 if len(assignment) else 0
    order = np.random.default_rng(seed).permutation(max(n, 1))
    return base[order[assignment] % len(base)]
