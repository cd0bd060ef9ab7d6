"""The room around each place: how far it lies from the nearest obstacle (DESIGN.md decision 19).

A place's clearance (terra.graph.places) is half the width of its terrain around it: the distance
to the nearest cell its terrain's GVD may not use, whether an obstacle stands there, another
terrain begins or the sensor never saw the ground. That is the right measure for the GVD, and the
wrong one for a robot's width: on a LiDAR-only map a hole in the scan one cell away (a gap between
far rings) left places on open ground with 0.4 m of clearance, which a 0.9 m wheelchair refused,
although the nearest object stood metres away.

The room is the distance (metres, in x, y) from the place to the nearest obstacle: the centre of a
blocked cell, or a map point that blocked one (in the grid's obstacle height band above the local
ground), whichever is nearer (`obstacle_points`), up to `ROOM_REACH`. Robot profiles check their
width against it (terra.tasks.robot), and the level routes (terra.graph.level_routes) join only
places with room for the wheelchair (`linking.level_route_clearance`): computed before them, it
is extended to the places they add. Beside an obstacle it reads no more than the clearance the
cells gave: the points alone read too much, on the simulated LiDAR-only campus 37 of 52 places
they let a wheelchair through stood nearer a true object's box than its half width (a far
object's points lie tens of centimetres apart, and its far side is never seen); the cells'
squares alone, too little (a place whose cell touches a bollard's cell at a corner reads 0.28 m,
and stands 0.64 m from it). An incremental update (terra.graph.update) reads the room of its new places on its
crops, whose context (`update.context_margin`, 8 m) reaches beyond `ROOM_REACH`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from terra.graph.grid import TerrainGrid

ROOM_REACH = 3.0  # metres: the most room a place reads (a robot needs a passage at most 6 m wide)
CHUNK = 1 << 22  # points per step of `obstacle_points`


def obstacle_points(points: np.ndarray, grid: TerrainGrid, band: tuple[float, float] | None) -> np.ndarray:
    """(M, 2) float64 map-frame x, y (metres) of the centres of the blocked cells of `grid` and of
    the map points (N, 3+) that stand `band` (low, high metres) above the local ground of one (what
    blocked it); none without a band (the grid then blocks nothing)."""
    if band is None or not grid.blocked.any():
        return np.zeros((0, 2))
    out = [grid.cell_centres(np.argwhere(grid.blocked))]
    for start in range(0, len(points), CHUNK):
        p = np.asarray(points[start : start + CHUNK], dtype=np.float64)
        rows, cols, inside = grid.cell_of(p)
        height = p[:, 2] - grid.ground[rows, cols]
        keep = inside & grid.blocked[rows, cols] & (height >= band[0]) & (height <= band[1])
        out.append(p[keep, :2])
    return np.vstack(out)


def place_room(position: np.ndarray, obstacles: np.ndarray, reach: float = ROOM_REACH) -> np.ndarray:
    """(P,) float64 metres: the distance in x, y from each place (`position` (P, 2+), map frame,
    metres) to the nearest of the `obstacles` (M, 2) (`obstacle_points`), `reach` where none lies
    within `reach` metres."""
    from scipy.spatial import cKDTree  # pyright: ignore[reportAttributeAccessIssue]  # stubless compiled module

    xy = np.atleast_2d(np.asarray(position, dtype=np.float64))[:, :2]
    if len(xy) == 0 or len(obstacles) == 0:
        return np.full(len(xy), float(reach))
    distance, _ = cKDTree(np.asarray(obstacles, dtype=np.float64)).query(xy, distance_upper_bound=reach)
    return np.minimum(distance, reach)
