"""The figure of `terra changes --figure`: the map from above in grey, terrain cells that changed class as
coloured squares (one colour per "before -> after" pair; ground an obstacle now blocks black, ground one
freed gold), and objects added (green triangles), removed (red
crosses) and moved (blue arrows from where they were, a hollow circle, to where they are). Map frame, metres."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from terra.bundle import Bundle
from terra.errors import TerraError
from terra.fileio import writing
from terra.mapping.changes import BLOCKED, ChangesResult
from terra.mapping.sessions import map_points
from terra.viz.places import distinct_palette
from terra.viz.style import Extent, figure_legend, new_figure, save_figure, topdown_axis, view_extent

MAX_GREY_POINTS = 200_000  # enough to read the site's layout; more only slows the drawing
KIND_STYLE = {"added": ("tab:green", "^"), "removed": ("tab:red", "X"), "moved": ("tab:blue", "o")}


BLOCKED_STYLE = {"to": (0.0, 0.0, 0.0), "from": (1.0, 0.84, 0.0)}
"""RGB 0..1 of ground an obstacle came to stand on ("sidewalk -> blocked": black, as a wall is drawn) and of
ground one left ("blocked -> asphalt": gold); neither is in the distinct palette."""


def pair_colours(pairs: list[str]) -> dict[str, tuple[float, float, float]]:
    """An RGB colour in 0..1 per "before -> after" terrain pair: `BLOCKED_STYLE` for a pair to or from
    blocked ground, and for the others, in name order, one from the distinct palette past its green, red
    and blue (the object markers'); the figure's and the viewer's."""
    palette = distinct_palette()
    out: dict[str, tuple[float, float, float]] = {}
    drawn = 0  # palette colours given so far
    for pair in sorted(set(pairs)):
        before, _, after = pair.partition(" -> ")
        if BLOCKED in (before, after):
            out[pair] = BLOCKED_STYLE["to" if after == BLOCKED else "from"]
            continue
        r, g, b = palette[(drawn + 4) % len(palette)]
        out[pair], drawn = (float(r), float(g), float(b)), drawn + 1
    return out


def _extent(points: np.ndarray, result: ChangesResult) -> Extent | None:
    """The site (the middle 98 % of the map's points each way: a LiDAR's few far returns would shrink it to
    a corner of the figure) and every change, with a margin."""
    where = [p[:2] for o in result.objects for p in (o.before, o.after) if p is not None]
    parts = [np.percentile(points[:, :2], [1, 99], axis=0)] if points.shape[0] else []
    parts += [np.asarray(where).reshape(-1, 2), result.terrain_cells.reshape(-1, 2)]
    both = np.vstack(parts)
    return view_extent(both) if both.shape[0] else None


def check_figure_path(path: Path) -> None:
    """TerraError (one line) unless `path` can name a PNG file: not a folder, in an existing folder, `.png`;
    checked before the changes are computed, so a typo costs nothing."""
    if path.suffix.lower() != ".png" or path.is_dir() or not path.parent.is_dir():
        raise TerraError(f"--figure {path}: expected a PNG file name (.png) in an existing folder")


def changes_figure(result: ChangesResult, path: Path) -> Path:
    """Draw `result` over its bundle's map points and write the PNG to `path` (TerraError, one line, when
    it cannot be written)."""
    bundle = Bundle(result.bundle)
    points = np.asarray(map_points(bundle), np.float64)  # either map layout
    n = points.shape[0]
    if n > MAX_GREY_POINTS:  # an even spread, the same on every run
        points = points[np.linspace(0, n - 1, MAX_GREY_POINTS).astype(np.int64)]
    extent = _extent(points, result)
    title = f"changes from session {result.first} to session {result.second}"
    fig, (ax,) = new_figure(panel_size=8.0, title=title, extent=extent)
    topdown_axis(ax, extent=extent)
    ax.scatter(points[:, 0], points[:, 1], s=0.2, c="0.75", linewidths=0, rasterized=True)
    handles: list = []
    for pair, colour in pair_colours(result.terrain_pairs).items():
        mine = np.array([p == pair for p in result.terrain_pairs])
        cells = result.terrain_cells[mine]
        ax.scatter(cells[:, 0], cells[:, 1], s=6, marker="s", color=colour, linewidths=0)
        area = mine.sum() * result.terrain_cell_area
        handles.append(Patch(color=colour, label=f"{pair} ({area:,.0f} m2)"))
    for change in result.objects:
        colour, marker = KIND_STYLE[change.change]
        where = change.after or change.before
        assert where is not None
        if change.change == "moved" and change.before is not None:
            ax.scatter([change.before[0]], [change.before[1]], s=40, marker=marker, facecolors="none", color=colour)
            ax.annotate(
                "", xy=where[:2], xytext=change.before[:2], arrowprops={"arrowstyle": "->", "color": colour, "lw": 1.5}
            )
        ax.scatter([where[0]], [where[1]], s=60, marker=marker, color=colour, edgecolors="black", linewidths=0.5)
        ax.annotate(
            change.name or ("LiDAR only" if change.entry < 0 else f"entry {change.entry}"),
            where[:2],
            fontsize=6,
            xytext=(4, 4),
            textcoords="offset points",
        )
    for kind, (colour, marker) in KIND_STYLE.items():
        count = sum(o.change == kind for o in result.objects)
        handles.append(Line2D([], [], color=colour, marker=marker, linestyle="", label=f"{kind} ({count})"))
    figure_legend(fig, handles, ncols=3)
    with writing(path, "figure"):
        return save_figure(fig, path)
