"""Shared look of Terra's figures: terrain colours, figure creation, deterministic PNG saving."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg", force=False)

import numpy as np  # noqa: E402
from matplotlib.axes import Axes  # noqa: E402
from matplotlib.backends.backend_agg import FigureCanvasAgg  # noqa: E402
from matplotlib.colors import to_rgb  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402

# The paper colours sidewalk red, grass green and asphalt blue; the others follow suit.
TERRAIN_COLOURS = {
    "sidewalk": "#d62728",
    "grass": "#2ca02c",
    "asphalt": "#1f77b4",
    "dirt": "#a0522d",
    "water": "#17becf",
    "gravel": "#9467bd",
    "sand": "#e6c229",
}
FALLBACK_COLOURS = ["#ff7f0e", "#e377c2", "#bcbd22", "#7f7f7f", "#8c564b", "#9467bd"]
OTHER_COLOUR = "#4d4d4d"  # non-terrain map points (objects, buildings, trees)
START_COLOUR = "#e31a1c"
GOAL_COLOUR = "#000000"
PATH_COLOUR = "#00bcd4"


def terrain_colour(name: str, index: int = 0) -> tuple[float, float, float]:
    """RGB (0..1) of a terrain class by name; unknown names cycle through fallback colours."""
    return to_rgb(TERRAIN_COLOURS.get(name.lower(), FALLBACK_COLOURS[index % len(FALLBACK_COLOURS)]))


def terrain_palette(terrain_classes: list[str]) -> np.ndarray:
    """(T + 1, 3) RGB rows: one per terrain class, then OTHER_COLOUR (index -1 maps to it)."""
    rows = [terrain_colour(n, i) for i, n in enumerate(terrain_classes)] + [to_rgb(OTHER_COLOUR)]
    return np.asarray(rows, dtype=np.float64)


def terrain_legend(ax: Axes, terrain_classes: list[str], other: str | None = "other", **kwargs) -> None:
    """A legend with one patch per terrain class (and `other` when given)."""
    handles = [Patch(color=terrain_colour(n, i), label=n) for i, n in enumerate(terrain_classes)]
    if other:
        handles.append(Patch(color=OTHER_COLOUR, label=other))
    ax.legend(handles=handles, loc=kwargs.pop("loc", "upper right"), fontsize=kwargs.pop("fontsize", 7), framealpha=0.85, **kwargs)


Extent = tuple[float, float, float, float]  # xmin, xmax, ymin, ymax (metres, map frame)


def new_figure(ncols: int = 1, nrows: int = 1, panel_size: float = 5.0, title: str | None = None,
               extent: Extent | None = None) -> tuple[Figure, list[Axes]]:
    """A figure of ncols x nrows panels `panel_size` inches wide, as tall as `extent`'s aspect
    asks (square without one), detached from pyplot (no GUI, no global state)."""
    aspect = 1.0
    if extent is not None:
        aspect = float(np.clip((extent[3] - extent[2]) / max(extent[1] - extent[0], 1e-9), 0.4, 2.0))
    height = panel_size * aspect + 0.6  # room for the axis labels and panel title
    fig = Figure(figsize=(panel_size * ncols, height * nrows + (0.4 if title else 0.0)), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(nrows, ncols, squeeze=False).ravel().tolist()
    if title:
        fig.suptitle(title, fontsize=12)
    return fig, axes


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
    """Write a PNG with no software/time metadata, so equal figures give equal bytes."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi, format="png", metadata={"Software": None})
    return path
