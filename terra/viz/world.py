"""Top-down picture of a simulated world: terrain colours, buildings, trees, objects, route, regions."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from terra.datasets.ground_truth import GroundTruth


def render_world_png(gt: GroundTruth, out: str | Path, trajectory_xy: np.ndarray | None = None,
                     colors: np.ndarray | None = None, title: str = "", dpi: int = 110) -> Path:
    """Write a top-down PNG (map frame, x right, y up, metres) of `gt` and the robot trajectory.

    colors: RGB uint8 per class id (defaults to the simulator's). Returns the path written.
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt
    from matplotlib.patches import Polygon as MplPolygon

    if colors is None:
        from terra.sim.classes import CLASS_COLORS as colors
    raster = gt.terrain
    h, w = raster.classes.shape
    x0, y0 = raster.origin
    x1, y1 = x0 + w * raster.resolution, y0 + h * raster.resolution
    ids = np.clip(raster.classes, 0, len(colors) - 1)
    image = colors[ids]
    side = 8.0
    fig, ax = plt.subplots(figsize=(side, side * (y1 - y0) / max(x1 - x0, 1e-9) + 0.6))
    ax.imshow(image, origin="lower", extent=(x0, x1, y0, y1), interpolation="nearest")
    big = max(x1 - x0, y1 - y0)
    for o in sorted(gt.objects, key=lambda o: o.center[2] + o.size[2] / 2):
        c, s = np.cos(o.yaw), np.sin(o.yaw)
        hx, hy = o.size[0] / 2, o.size[1] / 2
        corners = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]]) @ np.array([[c, s], [-s, c]]) + o.center[:2]
        rgb = colors[o.class_id] / 255.0 if 0 <= o.class_id < len(colors) else (0.5, 0.5, 0.5)
        if o.class_name == "tree":
            ax.add_patch(plt.Circle(o.center[:2], max(hx, hy), color=rgb, alpha=0.55, lw=0))
        else:
            edge = "k" if o.class_name == "building" else "none"
            ax.add_patch(MplPolygon(corners, closed=True, facecolor=rgb, edgecolor=edge, lw=0.4 if big < 800 else 0.1))
    if trajectory_xy is not None and len(trajectory_xy):
        ax.plot(trajectory_xy[:, 0], trajectory_xy[:, 1], color="#ff00ff", lw=1.2 if big < 800 else 0.5)
        ax.plot(*trajectory_xy[0, :2], marker="o", color="#ff00ff", ms=5)
    for r in gt.regions:
        poly = np.asarray(r.polygon)
        ax.add_patch(MplPolygon(poly, closed=True, fill=False, edgecolor="#ffffff", lw=1.0, ls="--"))
        if big < 800:
            ax.text(*poly.mean(axis=0), r.name, color="white", fontsize=6, ha="center", va="center",
                    bbox={"facecolor": "black", "alpha": 0.4, "pad": 1, "lw": 0})
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    if title:
        ax.set_title(title, fontsize=9)
    fig.tight_layout()
    out = Path(out)
    fig.savefig(out, dpi=dpi, metadata={"Software": None})
    plt.close(fig)
    return out
