"""Shared look of Terra's figures: terrain colours, figure creation, deterministic PNG saving."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg", force=False)

import numpy as np  # noqa: E402
from matplotlib.axes import Axes  # noqa: E402
from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: E402
from matplotlib.colors import to_rgb  # noqa: E402
from matplotlib.figure import Figure, FigureBase  # noqa: E402
from matplotlib.layout_engine import ConstrainedLayoutEngine  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402
from matplotlib.text import Text  # noqa: E402

# One terrain palette for every figure Terra draws (world.png, the report, terra render): the
# paper colours sidewalk red, grass green and asphalt blue; the others follow suit.
TERRAIN_COLOURS = {
    "sidewalk": "#d62728",
    "grass": "#2ca02c",
    "asphalt": "#1f77b4",
    "dirt": "#a0522d",
    "water": "#17becf",
    "gravel": "#9467bd",
    "sand": "#e6c229",
}
FALLBACK_COLOURS = ["#e377c2", "#bcbd22", "#8c564b", "#7f7f7f"]
OTHER_COLOUR = "#4d4d4d"  # what is not terrain: buildings, trees, objects (map points and ground truth alike)
UNSEEN_COLOUR = "#dedede"  # map points no camera labelled (LiDAR only)
TREE_COLOUR = "#6e6e6e"  # tree crowns in pictures of the ground truth
# Overlays, none of them a terrain colour: paths magenta, starts white, goals black, highlighted
# places orange; methods in retrieval figures get METHOD_COLOURS.
START_COLOUR = "#ffffff"
GOAL_COLOUR = "#000000"
PATH_COLOUR = "#ff00ff"
HIGHLIGHT_COLOUR = "#ff7f0e"
METHOD_COLOURS = ["#ff00ff", "#ff7f0e", "#6a3d9a", "#000000", "#b15928"]


def terrain_colour(name: str, index: int = 0) -> tuple[float, float, float]:
    """RGB (0..1) of a terrain class by name; unknown names cycle through fallback colours."""
    return to_rgb(TERRAIN_COLOURS.get(name.lower(), FALLBACK_COLOURS[index % len(FALLBACK_COLOURS)]))


def terrain_palette(terrain_classes: list[str]) -> np.ndarray:
    """(T + 1, 3) RGB rows: one per terrain class, then OTHER_COLOUR (index -1 maps to it)."""
    rows = [terrain_colour(n, i) for i, n in enumerate(terrain_classes)] + [to_rgb(OTHER_COLOUR)]
    return np.asarray(rows, dtype=np.float64)


def map_palette(terrain_classes: list[str]) -> np.ndarray:
    """(T + 2, 3) RGB rows for map points: terrain classes, not terrain, then no camera label."""
    return np.vstack([terrain_palette(terrain_classes), to_rgb(UNSEEN_COLOUR)])


def terrain_handles(terrain_classes: list[str], other: str | None = "not terrain") -> list:
    """Legend patches: one per terrain class, then `other` (not terrain) when given."""
    handles = [Patch(color=terrain_colour(n, i), label=n) for i, n in enumerate(terrain_classes)]
    if other:
        handles.append(Patch(color=OTHER_COLOUR, label=other))
    return handles


def terrain_legend(ax: Axes, terrain_classes: list[str], other: str | None = "other", **kwargs) -> None:
    """A legend with one patch per terrain class (and `other` when given), outside the axes
    (below them) so it never covers data."""
    figure_legend(ax.figure, terrain_handles(terrain_classes, other), **kwargs)


def figure_legend(
    fig: FigureBase, handles: list, ncols: int | None = None, fontsize: float = 8, title: str | None = None
) -> None:
    """One legend for the whole figure, below the panels (never over data)."""
    if not handles:
        return
    fig.legend(
        handles=handles,
        loc="outside lower center",
        ncols=ncols or min(len(handles), 6),
        fontsize=fontsize,
        frameon=False,
        title=title,
        title_fontsize=fontsize,
    )


Extent = tuple[float, float, float, float]  # xmin, xmax, ymin, ymax (metres, map frame)


def new_figure(
    ncols: int = 1, nrows: int = 1, panel_size: float = 5.0, title: str | None = None, extent: Extent | None = None
) -> tuple[Figure, list[Axes]]:
    """A figure of ncols x nrows panels `panel_size` inches wide, as tall as `extent`'s aspect
    asks (square without one), detached from pyplot (no GUI, no global state)."""
    aspect = 1.0
    if extent is not None:
        aspect = float(np.clip((extent[3] - extent[2]) / max(extent[1] - extent[0], 1e-9), 0.4, 2.0))
    height = panel_size * aspect + 0.6  # room for the axis labels and panel title
    layout = ConstrainedLayoutEngine(h_pad=0.06, w_pad=0.06, hspace=0.02, wspace=0.02, compress=True)
    fig = Figure(figsize=(panel_size * ncols, height * nrows + (0.4 if title else 0.0)), layout=layout)
    FigureCanvasAgg(fig)
    axes = fig.subplots(nrows, ncols, squeeze=False).ravel().tolist()
    if title:
        fig.suptitle(title, fontsize=12)
    return fig, axes


def _close_gaps(fig: Figure) -> None:
    """Move the figure's title down onto the panels and its legend up under them: equal-aspect
    map panels rarely fill the height the layout gave them, which otherwise leaves white bands
    inside the picture (the outer margins are cropped when saving)."""
    canvas = fig.canvas
    if not isinstance(canvas, FigureCanvasAgg):  # new_figure and every figure module attach Agg
        raise TypeError(f"figures are drawn on matplotlib's Agg canvas, not {type(canvas).__name__}")
    canvas.draw()  # lay the panels out once, then freeze them
    renderer = canvas.get_renderer()
    boxes = [box for ax in fig.axes if ax.get_visible() and (box := ax.get_tightbbox(renderer)) is not None]
    if not boxes:
        return
    fig.set_layout_engine("none")
    height = fig.bbox.height
    top, bottom = max(b.y1 for b in boxes) / height, min(b.y0 for b in boxes) / height
    # The figure's own title (set by suptitle): matplotlib keeps its Text there, and its public
    # get_suptitle returns only the string.
    title: Text | None = getattr(fig, "_suptitle", None)
    if title is not None:
        title.set_y(min(top + 0.01, 0.99))
        title.set_verticalalignment("bottom")
    for legend in fig.legends:
        legend.set_loc("upper center")
        legend.set_bbox_to_anchor((0.5, max(bottom - 0.005, 0.0)), transform=fig.transFigure)


def topdown_axis(ax: Axes, title: str | None = None, extent: Extent | None = None) -> None:
    """Equal-aspect map-frame axes labelled in metres, showing `extent` when given."""
    if extent is not None:
        ax.set_xlim(extent[0], extent[1])
        ax.set_ylim(extent[2], extent[3])
        ax.set_aspect("equal", adjustable="box")
    else:
        ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)", fontsize=8)
    ax.set_ylabel("y (m)", fontsize=8)
    ax.tick_params(labelsize=7)
    if title:
        ax.set_title(title, fontsize=10)


def view_extent(*xy: np.ndarray, margin: float = 0.05) -> Extent:
    """Extent covering all given point sets (n, >=2) with a relative margin on each side."""
    pts = np.vstack([np.asarray(p, float)[:, :2] for p in xy if len(p)])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    pad = margin * max(float((hi - lo).max()), 1.0)
    return (float(lo[0] - pad), float(hi[0] + pad), float(lo[1] - pad), float(hi[1] + pad))


def save_figure(fig: Figure, path: str | Path, dpi: int = 120) -> Path:
    """Write a PNG with no software/time metadata, so equal figures give equal bytes, cropped to
    what is drawn (no empty white bands)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    _close_gaps(fig)
    fig.savefig(path, dpi=dpi, format="png", metadata={"Software": None}, bbox_inches="tight", pad_inches=0.12)
    return path
