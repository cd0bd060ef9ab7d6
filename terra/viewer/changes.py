"""The changes layer of `terra view`: what changed between two sessions of a joined map (terra changes),
drawn in the scene. Objects added (green), removed (red) and moved (blue: a line from where the object
was to where it is) as spheres at their centres; terrain cells that changed class as squares at the
height of the map's ground there, one colour per "before -> after" pair. Map frame, metres; the colours
are those of `terra changes --figure` (terra/viz/changes.py)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from matplotlib.colors import to_rgb

from terra.mapping.changes import ChangesResult
from terra.viewer.scene import to_uint8
from terra.viz.changes import KIND_STYLE, pair_colours


def _rgb255(colour: str) -> tuple[int, int, int]:
    """A matplotlib colour as the 0..255 triple viser takes."""
    r, g, b = (int(v) for v in to_uint8(np.asarray(to_rgb(colour))))
    return r, g, b


KIND_COLOURS = {kind: _rgb255(colour) for kind, (colour, _) in KIND_STYLE.items()}  # the figure's markers
LIFT = 0.3  # metres the terrain squares float above the ground, so the points do not hide them


@dataclass
class ChangeMarkers:
    """What the scene draws of one ChangesResult. `objects[kind]`: (n, 3) centres of the changed objects
    (where they are now; where they were, for removed ones); `moves`: (m, 2, 3) from where each moved object
    was to where it is; `cells`: (c, 3) terrain cell centres lifted over the ground, `cell_colours` (c, 3)
    uint8, and `pairs` the "before -> after" pairs in colour order."""

    objects: dict[str, np.ndarray] = field(default_factory=dict)
    moves: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 3)))
    cells: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    cell_colours: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.uint8))
    pairs: list[str] = field(default_factory=list)


def change_markers(result: ChangesResult, ground_xyz: np.ndarray) -> ChangeMarkers:
    """The markers of `result`; terrain cells take the height of the nearest of `ground_xyz` (n, 3) map
    points in x-y (the drawn map's), plus LIFT."""
    markers = ChangeMarkers()
    for kind in KIND_COLOURS:
        where = [o.before if kind == "removed" else o.after for o in result.objects if o.change == kind]
        markers.objects[kind] = np.asarray([w for w in where if w is not None], np.float64).reshape(-1, 3)
    moved = [(o.before, o.after) for o in result.objects if o.change == "moved" and o.before and o.after]
    markers.moves = np.asarray(moved, np.float64).reshape(-1, 2, 3)
    cells = np.asarray(result.terrain_cells, np.float64).reshape(-1, 2)
    markers.pairs = sorted(set(result.terrain_pairs))
    if len(cells) and len(ground_xyz):
        from scipy.spatial import cKDTree  # pyright: ignore[reportAttributeAccessIssue]  (compiled, no stub)

        _, nearest = cKDTree(np.asarray(ground_xyz, np.float64)[:, :2]).query(cells)
        markers.cells = np.column_stack([cells, np.asarray(ground_xyz)[nearest, 2] + LIFT])
        colour_of = pair_colours(result.terrain_pairs)
        markers.cell_colours = to_uint8(np.array([colour_of[p] for p in result.terrain_pairs]).reshape(-1, 3))
    return markers


def changes_markdown(result: ChangesResult) -> str:
    """The GUI's summary of `result`: counts, each object change (class, where, how far), terrain areas."""
    counts = {kind: sum(o.change == kind for o in result.objects) for kind in KIND_COLOURS}
    lines = [
        f"**Session {result.first} -> {result.second}**, {result.observed_area_m2:,.0f} m² seen by both: "
        + ", ".join(f"{n} {kind}" for kind, n in counts.items())
    ]
    for o in result.objects[:12]:
        where = o.after if o.change != "removed" else o.before
        what = o.name or "object"
        far = f", moved {o.distance:.1f} m" if o.change == "moved" and o.distance is not None else ""
        at = f" at ({where[0]:.1f}, {where[1]:.1f})" if where is not None else ""
        lines.append(f"- {o.change}: {what}{at}{far}" + (f" ({o.region})" if o.region else ""))
    if len(result.objects) > 12:
        lines.append(f"- ... {len(result.objects) - 12} more (`terra changes --json`)")
    lines += [f"- terrain {t.before} -> {t.after}: {t.area_m2:.0f} m²" for t in result.terrain]
    return "\n".join(lines)
