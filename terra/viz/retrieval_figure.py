"""The retrieval figure: readable at a campus's scale (150 m and more), where a bench is a speck.

Left, the whole map with every ground-truth box (black) and every method's boxes (dashed, one
colour per method), and lettered frames where the insets look. Right, one zoomed inset per query
(up to `max_insets`): around one of its ground-truth objects (the one a prediction came nearest
to), that query's ground truth (thick black), other objects (grey) and each method's boxes for
the query, titled with what each method found and hit (Table II's counts). The legend is below.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import FigureBase
from matplotlib.lines import Line2D
from matplotlib.patches import Rectangle
from matplotlib.typing import LineStyleType

from terra.tasks.boxes import BoxSet
from terra.viz.raster import TopDownImage
from terra.viz.style import (
    METHOD_COLOURS,
    Extent,
    figure_legend,
    save_figure,
    terrain_handles,
    topdown_axis,
    view_extent,
)

LINE_STYLES: list[LineStyleType] = ["--", ":", "-.", (0, (5, 1, 1, 1)), (0, (1, 2))]
INSET_MIN_HALF_M = 3.0  # half the side of an inset, metres (larger for large objects)


def _short(query: str) -> str:
    """'Find the dumpster' -> 'dumpster' (the template's words before the object dropped)."""
    words = query.split()
    return " ".join(words[2:]) if len(words) > 2 and words[0].lower() == "find" and words[1].lower() == "the" else query


def inset_centre(
    q: int, gt: BoxSet, gt_query: np.ndarray, predictions: dict[str, tuple[BoxSet, np.ndarray]]
) -> np.ndarray:
    """xy (metres) of the ground-truth object of query q that a prediction for q came nearest to
    (its first object when nothing was predicted for q)."""
    mine = np.flatnonzero(gt_query == q)
    centres = gt.center[mine, :2]
    found = [boxes.center[query == q, :2] for boxes, query in predictions.values() if np.any(query == q)]
    if not found:
        return centres[0]
    pred = np.vstack(found)
    d = np.linalg.norm(centres[:, None, :] - pred[None, :, :], axis=2).min(axis=1)
    return centres[int(np.argmin(d))]


def _inset_extent(centre: np.ndarray, q: int, gt: BoxSet, gt_query: np.ndarray) -> Extent:
    sizes = gt.size[gt_query == q, :2]
    half = max(INSET_MIN_HALF_M, float(sizes.max(initial=0)) * 1.2 + 1.0)
    return (float(centre[0] - half), float(centre[0] + half), float(centre[1] - half), float(centre[1] + half))


def _layout(n: int) -> tuple[int, int]:
    """(rows, inset columns): at least two rows so the overview is not a thumbnail."""
    rows = max(2, int(np.ceil(np.sqrt(n))))
    return rows, max(1, int(np.ceil(n / rows)))


def boxes_figure(
    path: str | Path,
    gt: BoxSet,
    predictions: dict[str, tuple[BoxSet, np.ndarray]],
    queries: list[str],
    gt_query: np.ndarray,
    background: TopDownImage | None = None,
    dpi: int = 120,
    extent: Extent | None = None,
    counts: dict[str, list[tuple[int, int]]] | None = None,
    max_insets: int = 16,
    terrain_classes: list[str] | None = None,
) -> Path:
    """Retrieved boxes against ground truth (see the module docstring). `predictions` maps a
    method to (boxes, query index per box); `gt_query` is the query index of each ground-truth
    box; `counts` maps a method to (found, hits) per query, as Table II counts them. With
    `terrain_classes` (the background's), the legend names the terrain colours the insets show."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    gt_query = np.asarray(gt_query, dtype=np.int64)
    shown = [q for q in range(len(queries)) if np.any(gt_query == q)][:max_insets]
    rows, cols = _layout(len(shown))
    inset = 2.5
    fig = Figure(figsize=(inset * (rows + cols), inset * rows + 0.9), layout="constrained")
    FigureCanvasAgg(fig)
    grid = fig.add_gridspec(rows, rows + cols)
    overview = fig.add_subplot(grid[:, :rows])
    extent = extent or view_extent(gt.center)
    methods = list(predictions)
    look = _Look(
        {m: METHOD_COLOURS[i % len(METHOD_COLOURS)] for i, m in enumerate(methods)},
        {m: LINE_STYLES[i % len(LINE_STYLES)] for i, m in enumerate(methods)},
    )
    corners = gt.footprint_corners()
    _draw(overview, background, corners, None, predictions, look.colour, look.style, thin=True)
    topdown_axis(overview, f"all {len(gt)} ground-truth objects and the boxes of each method", extent)
    for k, q in enumerate(shown):
        ax = fig.add_subplot(grid[k % rows, rows + k // rows])
        window = _inset_extent(inset_centre(q, gt, gt_query, predictions), q, gt, gt_query)
        _draw(ax, background, corners, gt_query == q, predictions, look.colour, look.style, False, q, window)
        letter = chr(ord("a") + k)
        _mark_inset(overview, window, letter)
        title = f"({letter}) {_short(queries[q])}: {int(np.count_nonzero(gt_query == q))} true"
        if counts:
            title += "\n" + ", ".join(f"{m} {counts[m][q][0]}/{counts[m][q][1]}" for m in methods if m in counts)
        _inset_axis(ax, title, window)
    _boxes_legend(fig, methods, look, bool(counts), terrain_classes, same_boxes(predictions))
    fig.suptitle("Object retrieval: ground-truth boxes (solid) and retrieved boxes (dashed)", fontsize=12)
    return save_figure(fig, path, dpi)


@dataclass(frozen=True)
class _Look:
    """Per method, the colour and the line style of its boxes."""

    colour: dict[str, str]
    style: dict[str, LineStyleType]


def _mark_inset(overview: Axes, window: Extent, letter: str) -> None:
    """The inset's window as a black frame on the overview, with its letter at the top-left corner."""
    overview.add_patch(
        Rectangle(
            (window[0], window[2]),
            window[1] - window[0],
            window[3] - window[2],
            fill=False,
            edgecolor="black",
            linewidth=0.9,
            zorder=7,
        )
    )
    overview.annotate(
        letter,
        (window[0], window[3]),
        fontsize=7,
        fontweight="bold",
        zorder=8,
        va="bottom",
        bbox={"facecolor": "white", "edgecolor": "none", "pad": 0.5, "alpha": 0.85},
    )


def same_boxes(predictions: dict[str, tuple[BoxSet, np.ndarray]]) -> dict[str, str]:
    """{method: the earlier method whose boxes (centres, sizes, yaws and queries) it repeats
    exactly}: drawn on top of each other, one set would hide the other without a word."""
    same: dict[str, str] = {}
    methods = list(predictions)
    for i, m in enumerate(methods):
        boxes, query = predictions[m]
        for earlier in methods[:i]:
            other, other_query = predictions[earlier]
            if (
                len(boxes) == len(other)
                and np.array_equal(query, other_query)
                and all(
                    np.array_equal(a, b)
                    for a, b in zip((boxes.center, boxes.size, boxes.yaw), (other.center, other.size, other.yaw))
                )
            ):
                same[m] = same.get(earlier, earlier)
                break
    return same


def _boxes_legend(
    fig: FigureBase,
    methods: list[str],
    look: _Look,
    with_counts: bool,
    terrain_classes: list[str] | None,
    same: dict[str, str],
) -> None:
    handles = [
        Line2D([], [], color="black", linewidth=1.8, label="ground truth of the query"),
        Line2D([], [], color="#9a9a9a", linewidth=0.8, label="other objects"),
    ]
    handles += [
        Line2D(
            [],
            [],
            color=look.colour[m],
            linestyle=look.style[m],
            linewidth=1.6,
            label=f"{m} boxes" + (f" (the same as {same[m]}'s, drawn over them)" if m in same else ""),
        )
        for m in methods
    ]
    ncols = len(handles)
    if terrain_classes:
        # The insets zoom into the faded terrain background: its colours need naming there too.
        terrain = terrain_handles(terrain_classes, "not terrain")
        for patch in terrain:
            patch.set_alpha(0.45)
        handles += terrain
        ncols = max(ncols, (len(handles) + 1) // 2)
    title = "inset titles: method found / hits, as in Table II" if with_counts else None
    figure_legend(fig, handles, ncols=ncols, title=title)


def _in_window(quads: np.ndarray, window: Extent | None) -> np.ndarray:
    """(n,) whether each footprint (n, 4, 2) reaches into `window` (all when None)."""
    if window is None or len(quads) == 0:
        return np.ones(len(quads), dtype=bool)
    lo, hi = quads.min(axis=1), quads.max(axis=1)
    return (hi[:, 0] >= window[0]) & (lo[:, 0] <= window[1]) & (hi[:, 1] >= window[2]) & (lo[:, 1] <= window[3])


def _outlines(ax, quads: np.ndarray, **kwargs) -> None:
    """Footprints as one collection (one artist, not one per box: a figure has thousands)."""
    from matplotlib.collections import PolyCollection

    if len(quads):
        ax.add_collection(PolyCollection(list(quads), closed=True, facecolors="none", **kwargs))


def _draw(
    ax,
    background,
    corners,
    highlight,
    predictions,
    colour,
    style,
    thin: bool,
    query: int | None = None,
    window: Extent | None = None,
) -> None:
    """Ground truth (highlighted ones thick black, the rest grey; all black on the overview) and
    the predictions (all, or those of `query`), only what reaches into `window`."""
    if background is not None:
        (background if window is None else background.crop(window)).show(ax, alpha=0.35 if thin else 0.25)
    seen = _in_window(corners, window)
    strong = np.ones(len(corners), dtype=bool) if thin else np.asarray(highlight, dtype=bool)
    _outlines(ax, corners[seen & strong], edgecolors="black", linewidths=0.6 if thin else 1.8, zorder=4)
    _outlines(ax, corners[seen & ~strong], edgecolors="#9a9a9a", linewidths=0.8, zorder=4)
    for method, (boxes, assigned) in predictions.items():
        quads = boxes.footprint_corners()
        keep = _in_window(quads, window) & ((np.asarray(assigned) == query) if query is not None else True)
        _outlines(
            ax,
            quads[keep],
            edgecolors=colour[method],
            linestyles=[style[method]],
            linewidths=0.7 if thin else 1.6,
            zorder=5,
        )


def _inset_axis(ax, title: str, window: Extent) -> None:
    ax.set_xlim(window[0], window[1])
    ax.set_ylim(window[2], window[3])
    ax.set_aspect("equal", adjustable="box")
    ax.tick_params(labelsize=6, length=2, pad=1)
    ax.set_title(title, fontsize=7.5)
