"""Drawing the places layer: nodes coloured by terrain or by region, edges styled by kind."""

from __future__ import annotations

import numpy as np
from matplotlib.axes import Axes
from matplotlib.collections import LineCollection
from matplotlib.typing import LineStyleType

from terra.graph.scene_graph import EDGE_BRIDGE, EDGE_CROSS_TERRAIN, EDGE_GVD, EDGE_LEVEL_ROUTE, SceneGraph
from terra.viz.style import Extent, terrain_palette


def marker_size(count: int) -> float:
    """Scatter marker area (points^2) that stays readable from ten to ten thousand nodes."""
    return float(np.clip(4000.0 / max(count, 1), 3.0, 30.0))


# kind: (label, colour, width, line style); cross-terrain links stand out
EDGE_STYLES: dict[int, tuple[str, str, float, LineStyleType]] = {
    EDGE_GVD: ("along one terrain", "#8c8c8c", 0.6, "solid"),
    EDGE_CROSS_TERRAIN: ("cross-terrain link", "#000000", 1.3, "solid"),
    EDGE_BRIDGE: ("bridge (joins components)", "#000000", 1.0, "dashed"),
    EDGE_LEVEL_ROUTE: ("route over level ground", "#1f77b4", 1.1, "solid"),
}


def extent_with_places(extent: Extent | None, sg: SceneGraph, margin: float = 0.03) -> Extent | None:
    """`extent` (x0, x1, y0, y1 metres, map frame) grown to hold every place with `margin` (a share
    of the places' larger side) around them: a view of the evaluated world (the ground-truth
    raster) leaves out places built from far LiDAR returns, and their edges would run off the
    frame. None stays None (the axes then fit the data)."""
    if extent is None or len(sg.places) == 0:
        return extent
    xy = np.asarray(sg.places.position, dtype=np.float64)[:, :2]
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    pad = margin * max(float((hi - lo).max()), 1.0)
    return (
        min(extent[0], float(lo[0] - pad)),
        max(extent[1], float(hi[0] + pad)),
        min(extent[2], float(lo[1] - pad)),
        max(extent[3], float(hi[1] + pad)),
    )


def draw_place_edges(
    ax: Axes, sg: SceneGraph, colour: str | None = None, width: float | None = None, alpha: float = 0.8
) -> dict[int, int]:
    """Place edges as line segments styled by kind (EDGE_STYLES), or all in `colour` when given;
    returns the number of edges drawn per kind."""
    counts: dict[int, int] = {}
    if len(sg.place_edges) == 0:
        return counts
    xy = sg.places.position[:, :2]
    for kind, (_, kind_colour, kind_width, style) in EDGE_STYLES.items():
        mask = sg.place_edge_kind == kind
        if mask.any():
            counts[kind] = int(np.count_nonzero(mask))
            ax.add_collection(
                LineCollection(
                    list(xy[sg.place_edges[mask]]),
                    colors=colour or kind_colour,
                    linewidths=width or kind_width,
                    alpha=alpha,
                    linestyles=style,
                    zorder=1.5 if kind != EDGE_GVD else 1,
                )
            )
    return counts


def edge_handles(counts: dict[int, int]) -> list:
    """Legend lines for the edge kinds drawn, with their counts."""
    from matplotlib.lines import Line2D

    return [
        Line2D([], [], color=c, linewidth=w, linestyle=st, label=f"{label} ({counts[kind]})")
        for kind, (label, c, w, st) in EDGE_STYLES.items()
        if counts.get(kind)
    ]


def draw_places(
    ax: Axes,
    sg: SceneGraph,
    colours: np.ndarray | None = None,
    edges: bool | str = True,
    size: float | None = None,
    zorder: int = 2,
) -> None:
    """Place nodes at their map-frame xy, coloured by terrain unless `colours` (P, 3) is given;
    edges styled by kind (True), all in one colour (a colour string) or not drawn (False)."""
    if edges:
        draw_place_edges(ax, sg, colour=None if edges is True else edges)
    if len(sg.places) == 0:
        return
    if colours is None:
        colours = terrain_palette(sg.terrain_classes)[sg.places.terrain]
    xy = sg.places.position
    ax.scatter(
        xy[:, 0],
        xy[:, 1],
        s=size or marker_size(len(sg.places)),
        c=colours,
        edgecolors="black",
        linewidths=0.2,
        zorder=zorder,
    )
    ax.autoscale_view()


def region_colours(assignment: np.ndarray, seed: int = 0) -> np.ndarray:
    """(P, 3) distinct-looking colours per region id: a fixed shuffle of a qualitative palette so
    neighbouring region ids (often neighbouring regions) do not share a hue."""
    from matplotlib import colormaps

    base = np.vstack([colormaps["tab20"](np.arange(20))[:, :3], colormaps["tab20b"](np.arange(20))[:, :3]])
    n = int(assignment.max()) + 1 if len(assignment) else 0
    order = np.random.default_rng(seed).permutation(max(n, 1))
    return base[order[assignment] % len(base)]


def distinct_palette() -> np.ndarray:
    """(40, 3) qualitative colours, the most different first: tab10's ten hues, then their light
    variants (tab20's odd entries), then tab20b's. A level of three regions takes the first three
    (blue, orange, green), never three shades of one hue."""
    from matplotlib import colormaps

    return np.vstack(
        [
            colormaps["tab10"](np.arange(10))[:, :3],
            colormaps["tab20"](np.arange(1, 20, 2))[:, :3],
            colormaps["tab20b"](np.arange(20))[:, :3],
        ]
    )


def region_adjacency(sg: SceneGraph, assignment: np.ndarray) -> list[set[int]]:
    """Per region id, the ids of the regions that a place edge joins it to."""
    n = int(assignment.max()) + 1 if len(assignment) else 0
    neighbours: list[set[int]] = [set() for _ in range(n)]
    if len(sg.place_edges):
        a, b = assignment[sg.place_edges[:, 0]], assignment[sg.place_edges[:, 1]]
        for u, v in zip(a[a != b].tolist(), b[a != b].tolist()):
            neighbours[u].add(v)
            neighbours[v].add(u)
    return neighbours


def adjacent_region_colours(sg: SceneGraph, assignment: np.ndarray) -> np.ndarray:
    """(P, 3) colours per place by its region (`assignment`, region id per place) such that two
    regions a place edge joins never share a colour (while the palette is larger than a region's
    number of neighbours), spread over the palette. Greedy colouring, regions with the most
    neighbours first; each takes the least-used colour none of its neighbours has (the first on
    ties), so a level of a few regions gets the palette's most distinct first colours."""
    palette = distinct_palette()
    neighbours = region_adjacency(sg, assignment)
    colour = np.full(len(neighbours), -1, dtype=np.int64)
    used = np.zeros(len(palette), dtype=np.int64)
    for region in sorted(range(len(neighbours)), key=lambda r: (-len(neighbours[r]), r)):
        free = np.ones(len(palette), dtype=bool)
        free[[colour[v] for v in neighbours[region] if colour[v] >= 0]] = False
        choices = np.flatnonzero(free) if free.any() else np.arange(len(palette))
        colour[region] = int(choices[np.argmin(used[choices])])
        used[colour[region]] += 1
    return palette[colour[assignment]] if len(assignment) else np.zeros((0, 3))
