"""Gravity-aligned oriented bounding boxes fitted to object points.

A box is a centre (3,) and size (3,) in metres, map frame, and a yaw in radians about +z: size[0]
lies along the box's x axis, which points along (cos yaw, sin yaw). Boxes are gravity aligned (no
roll or pitch), as outdoor objects stand on the ground and as the ground-truth boxes are.
`BoxSet` holds n such boxes as arrays, for the metrics (terra.eval.metrics.boxes) and the figures.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import overload

import numpy as np
import shapely
from numpy.typing import ArrayLike

from terra.errors import TerraError


@dataclass(frozen=True)
class OrientedBox:
    """center, size: (3,) metres; yaw: radians in [-pi/2, pi/2), size[0] >= size[1]."""

    center: np.ndarray
    size: np.ndarray
    yaw: float

    def corners_xy(self) -> np.ndarray:
        """(4, 2) footprint corners, counter-clockwise, metres."""
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        half = self.size[:2] / 2
        local = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * half
        return local @ np.array([[c, s], [-s, c]]) + self.center[:2]


@dataclass(init=False)
class BoxSet:
    """n oriented boxes: center (n, 3) metres, size (n, 3) metres (box axes), yaw (n,) radians."""

    center: np.ndarray
    size: np.ndarray
    yaw: np.ndarray

    def __init__(self, center: ArrayLike, size: ArrayLike, yaw: ArrayLike) -> None:
        """Any array-likes of those shapes (nested lists too), stored as float64 arrays."""
        self.center = np.asarray(center, dtype=np.float64).reshape(-1, 3)
        self.size = np.asarray(size, dtype=np.float64).reshape(-1, 3)
        self.yaw = np.asarray(yaw, dtype=np.float64).reshape(-1)
        if not (len(self.center) == len(self.size) == len(self.yaw)):
            raise ValueError(
                f"box arrays disagree: {len(self.center)} centres, {len(self.size)} sizes, {len(self.yaw)} yaws"
            )
        if np.any(self.size < 0):
            raise ValueError("box sizes must be non-negative")

    def __len__(self) -> int:
        return int(self.center.shape[0])

    def __getitem__(self, index) -> BoxSet:
        return BoxSet(self.center[index], self.size[index], self.yaw[index])

    @classmethod
    def empty(cls) -> BoxSet:
        return cls(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))

    @classmethod
    def from_objects(cls, objects: Iterable) -> BoxSet:
        """From anything with `.center`, `.size`, `.yaw` (ground-truth ObjectBox, FoundObject)."""
        objects = list(objects)
        if not objects:
            return cls.empty()
        return cls(
            np.stack([np.asarray(o.center, float) for o in objects]),
            np.stack([np.asarray(o.size, float) for o in objects]),
            np.array([float(o.yaw) for o in objects]),
        )

    @property
    def volume(self) -> np.ndarray:
        """(n,) cubic metres."""
        return np.prod(self.size, axis=1)

    def footprint_corners(self) -> np.ndarray:
        """(n, 4, 2) footprint corners in the map frame, counter-clockwise."""
        half = self.size[:, None, :2] / 2.0 * np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], float)[None]
        c, s = np.cos(self.yaw)[:, None], np.sin(self.yaw)[:, None]
        x = c * half[..., 0] - s * half[..., 1]
        y = s * half[..., 0] + c * half[..., 1]
        return np.stack([x, y], axis=-1) + self.center[:, None, :2]

    def footprints(self) -> np.ndarray:
        """(n,) shapely polygons of the footprints."""
        return np.asarray(shapely.polygons(self.footprint_corners()))

    def contains(self, points: np.ndarray) -> np.ndarray:
        """(n, m) whether box i contains point j (points (m, 3), map frame; boundary counts as inside)."""
        points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        d = points[None, :, :] - self.center[:, None, :]  # (n, m, 3)
        c, s = np.cos(self.yaw)[:, None], np.sin(self.yaw)[:, None]
        # Rotate by -yaw into the box axes.
        local = np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1], d[..., 2]], axis=-1)
        eps = 1e-9
        return np.all(np.abs(local) <= self.size[:, None, :] / 2.0 + eps, axis=-1)


@overload
def wrap_half_turn(yaw: float) -> float: ...


@overload
def wrap_half_turn(yaw: np.ndarray) -> np.ndarray: ...


def wrap_half_turn(yaw: float | np.ndarray) -> float | np.ndarray:
    """Axis directions in radians, folded into [-pi/2, pi/2) (a box is symmetric under pi)."""
    folded = (np.asarray(yaw, dtype=np.float64) + np.pi / 2) % np.pi - np.pi / 2
    return float(folded) if folded.ndim == 0 else folded


def fit_oriented_boxes(points: np.ndarray, groups: np.ndarray, padding: float = 0.0) -> list[OrientedBox]:
    """One box per group of points, fitted in one vectorised shapely call: the footprint is the
    minimum-area rectangle around the group's xy convex hull (rotating calipers) and the z extent
    spans its points.

    points: (n, 3) metres, map frame. groups: (n,) group ids 0..G-1, every id used at least once.
    padding: metres added to every dimension. The x axis is the rectangle's longer side; collinear
    points give a zero width and a single xy a zero footprint (before padding).
    """
    pts = np.asarray(points, dtype=np.float64)
    groups = np.asarray(groups, dtype=np.int64)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0 or groups.shape != (len(pts),):
        raise ValueError(f"expected (n, 3) points with n >= 1 and (n,) groups, got {pts.shape} and {groups.shape}")
    order = np.argsort(groups, kind="stable")
    pts, groups = pts[order], groups[order]
    n_groups = int(groups[-1]) + 1
    starts = np.searchsorted(groups, np.arange(n_groups))
    if np.any(np.diff(np.append(starts, len(groups))) == 0):
        raise ValueError("every group id 0..G-1 needs at least one point")
    z_lo, z_hi = np.minimum.reduceat(pts[:, 2], starts), np.maximum.reduceat(pts[:, 2], starts)
    rects = shapely.minimum_rotated_rectangle(shapely.multipoints(pts[:, :2], indices=groups))
    coords, owner = shapely.get_coordinates(rects, return_index=True)
    counts = np.bincount(owner, minlength=n_groups)
    first = np.concatenate([[0], np.cumsum(counts)[:-1]])
    is_rect = (shapely.get_type_id(rects) == shapely.GeometryType.POLYGON) & (counts == 5)
    # Rectangles: corners 0..3 of each closed ring; the first two edges are its two sides.
    corners = coords[first[is_rect, None] + np.arange(4)]  # (R, 4, 2)
    edges = corners[:, 1:3] - corners[:, 0:2]  # (R, 2, 2): side 0 = c1 - c0, side 1 = c2 - c1
    lengths = np.linalg.norm(edges, axis=2)
    long_side = np.argmax(lengths, axis=1)
    r = np.arange(len(corners))
    axis = np.zeros((n_groups, 2))
    size_xy = np.zeros((n_groups, 2))
    center_xy = np.zeros((n_groups, 2))
    axis[is_rect] = edges[r, long_side]
    size_xy[is_rect] = np.column_stack([lengths[r, long_side], lengths[r, 1 - long_side]])
    center_xy[is_rect] = corners.mean(axis=1)
    for g in np.flatnonzero(~is_rect):  # collinear or coincident footprints (rare)
        ring = coords[first[g] : first[g] + counts[g]]
        ends = ring[[0, -1]]
        axis[g] = ends[1] - ends[0] if np.any(ends[1] != ends[0]) else (1.0, 0.0)
        size_xy[g] = (np.linalg.norm(ends[1] - ends[0]), 0.0)
        center_xy[g] = ends.mean(axis=0)
    yaw = wrap_half_turn(np.arctan2(axis[:, 1], axis[:, 0]))
    centers = np.column_stack([center_xy, (z_lo + z_hi) / 2])
    sizes = np.column_stack([size_xy, z_hi - z_lo]) + padding
    return [OrientedBox(center=centers[g], size=sizes[g], yaw=float(yaw[g])) for g in range(n_groups)]


def fit_oriented_box(points: np.ndarray, padding: float = 0.0) -> OrientedBox:
    """The box of one point set (n, 3), n >= 1: see fit_oriented_boxes."""
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0:
        raise ValueError(f"expected (n, 3) points with n >= 1, got shape {pts.shape}")
    return fit_oriented_boxes(pts, np.zeros(len(pts), dtype=np.int64), padding)[0]


def _hull_edges(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Directions (k,) radians and lengths (k,) metres of the edges of the convex hull of xy
    points (n, 2); none when the hull is a point or a segment."""
    hull = shapely.convex_hull(shapely.multipoints(xy))
    if shapely.get_type_id(hull) != shapely.GeometryType.POLYGON:
        return np.zeros(0), np.zeros(0)
    ring = shapely.get_coordinates(hull)
    d = np.diff(ring, axis=0)
    return np.arctan2(d[:, 1], d[:, 0]), np.hypot(d[:, 0], d[:, 1])


def edge_yaw(xy: np.ndarray, tolerance: float = 0.15, agree_deg: float = 5.0) -> float | None:
    """The yaw (radians) of a footprint's dominant edges: of the rectangles square to a hull edge
    (the minimum-area one is among them) within `tolerance` of the smallest area, the one whose
    sides run along the most hull-edge length (edges within `agree_deg` of its sides, modulo 90
    degrees). None for a hull that is a point or a segment.

    An L-shaped footprint (two faces of a box seen from one corner) has a right-triangle hull;
    the rectangle on its hypotenuse is exactly as small as the one on its legs, so the minimum-area
    rule alone turns the box by the triangle's angle (about 30 degrees for a 2 x 1.3 m dumpster).
    The legs are two hull edges, the hypotenuse one: the legs win."""
    angle, length = _hull_edges(np.asarray(xy, dtype=np.float64)[:, :2])
    if len(angle) == 0:
        return None
    c, s = np.cos(angle), np.sin(angle)
    hull = np.asarray(xy, dtype=np.float64)[:, :2]
    u = hull @ np.stack([c, s])  # (n, k): along each candidate
    v = hull @ np.stack([-s, c])
    area = np.ptp(u, axis=0) * np.ptp(v, axis=0)
    off = np.abs((angle[None, :] - angle[:, None] + np.pi / 4) % (np.pi / 2) - np.pi / 4)  # (k, k) mod 90 degrees
    support = (off <= np.radians(agree_deg)) @ length
    fits = area <= (1.0 + tolerance) * area.min() + 1e-12
    best = int(np.flatnonzero(fits)[np.argmax(support[fits])])
    return float(angle[best])


def closeness_yaw(xy: np.ndarray, floor: float = 0.1, step_deg: float = 1.0) -> float | None:
    """The yaw (radians) whose bounding rectangle hugs a footprint's points (n, 2) most closely:
    each point scores 1 / max(d, `floor`), d its distance (metres) to the nearest side of the
    rectangle at that yaw, over the hull's edge directions and a `step_deg` grid of [0, 90)
    degrees (a rectangle is the same turned by 90). None for a hull that is a point or a segment.

    This is the closeness criterion of L-shape fitting: a partial view of a car (one or two faces,
    rounded corners, the roof and hood inside the outline) puts most points on one or two sides of
    the right rectangle, while the smallest rectangle may hang on a rounded corner's chord.
    `floor` keeps one point exactly on a side from outweighing the rest; 0.1 m (a few times a
    LiDAR's range noise, about a rounded bumper's bulge) was chosen from 0.02, 0.05, 0.1 and 0.2
    on three KITTI cars (benchmarks/RESULTS.md, issue 27) and is flat on synthetic ones. Hull
    edges come first, so on ties (clean, exact faces) a hull edge wins and an exact box keeps its
    exact yaw."""
    xy = np.asarray(xy, dtype=np.float64)[:, :2]
    angle, _ = _hull_edges(xy)
    if len(angle) == 0:
        return None
    candidates = np.concatenate([angle % (np.pi / 2), np.radians(np.arange(0.0, 90.0, step_deg))])
    c, s = np.cos(candidates), np.sin(candidates)
    u = xy @ np.stack([c, s])  # (n, k): along each candidate axis
    v = xy @ np.stack([-s, c])
    du = np.minimum(u - u.min(axis=0), u.max(axis=0) - u)
    dv = np.minimum(v - v.min(axis=0), v.max(axis=0) - v)
    score = (1.0 / np.maximum(np.minimum(du, dv), floor)).sum(axis=0)
    return float(candidates[int(np.argmax(score))])


def _extents_at_yaw(points: np.ndarray, groups: np.ndarray, yaw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per group, the centre (G, 2) and size (G, 2) of the rectangle with axes at `yaw` (G,)
    radians that bounds its xy points; points sorted by group, every group present."""
    starts = np.searchsorted(groups, np.arange(len(yaw)))
    c, s = np.cos(yaw)[groups], np.sin(yaw)[groups]
    u = c * points[:, 0] + s * points[:, 1]
    v = -s * points[:, 0] + c * points[:, 1]
    lo = np.column_stack([np.minimum.reduceat(u, starts), np.minimum.reduceat(v, starts)])
    hi = np.column_stack([np.maximum.reduceat(u, starts), np.maximum.reduceat(v, starts)])
    mid = (lo + hi) / 2
    cy, sy = np.cos(yaw), np.sin(yaw)
    centre = np.column_stack([cy * mid[:, 0] - sy * mid[:, 1], sy * mid[:, 0] + cy * mid[:, 1]])
    return centre, hi - lo


def _prefer_context(
    xy: np.ndarray,
    groups: np.ndarray,
    context: np.ndarray,
    prefer_context: float,
    yaw: np.ndarray,
    centre: np.ndarray,
    size_xy: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(yaw (G,), centre (G, 2), size (G, 2)): per group, the rectangle at its context direction
    (`context` radians, NaN = none) where that is at most `prefer_context` times the area of the
    given minimum-area one, else the given one. xy (n, 2) sorted by `groups`."""
    has = np.isfinite(context)
    c_centre, c_size = _extents_at_yaw(xy, groups, np.where(has, context, 0.0))
    take = has & (np.prod(c_size, axis=1) <= prefer_context * np.prod(size_xy, axis=1) + 1e-9)
    swap = c_size[:, 1] > c_size[:, 0]
    c_yaw = wrap_half_turn(np.where(swap, context + np.pi / 2, context))
    c_size = np.where(swap[:, None], c_size[:, ::-1], c_size)
    return (
        np.where(take, c_yaw, yaw),
        np.where(take[:, None], c_centre, centre),
        np.where(take[:, None], c_size, size_xy),
    )


def _z_extent(
    z: np.ndarray, groups: np.ndarray, n_groups: int, ground: np.ndarray, padding: float
) -> tuple[np.ndarray, np.ndarray]:
    """(bottom, top) (G,) metres per group: from the ground height `ground` (G,) when known and
    below the lowest point, else the lowest point less half the padding, up to the highest point
    plus half the padding. z (n,) sorted by `groups`, every group present."""
    starts = np.searchsorted(groups, np.arange(n_groups))
    z_hi = np.maximum.reduceat(z, starts) + padding / 2
    on_ground = np.isfinite(ground)
    z_lo = np.where(
        on_ground,
        np.minimum(np.minimum.reduceat(z, starts), np.where(on_ground, ground, 0.0)),
        np.minimum.reduceat(z, starts) - padding / 2,
    )
    return z_lo, z_hi


def _edge_rectangles(xy: np.ndarray, groups: np.ndarray, n_groups: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(yaw (G,), centre (G, 2), size (G, 2)) per group of xy points (n, 2) sorted by group: the
    rectangle at the yaw that hugs the footprint closest (closeness_yaw), the x axis along its
    longer side; the minimum-area rectangle where the hull is a point or a segment."""
    rect = fit_oriented_boxes(np.column_stack([xy, np.zeros(len(xy))]), groups)
    yaw = np.array([b.yaw for b in rect])
    starts = np.searchsorted(groups, np.arange(n_groups + 1))
    for g in range(n_groups):
        found = closeness_yaw(xy[starts[g] : starts[g + 1]])
        if found is not None:
            yaw[g] = found
    centre, size = _extents_at_yaw(xy, groups, yaw)
    swap = size[:, 1] > size[:, 0]
    return wrap_half_turn(np.where(swap, yaw + np.pi / 2, yaw)), centre, np.where(swap[:, None], size[:, ::-1], size)


def _per_group(value: ArrayLike | None, n_groups: int, what: str) -> np.ndarray | None:
    """A (3,) or (G, 3) argument as (G, 3) float64 (None stays None); TerraError otherwise."""
    if value is None:
        return None
    array = np.asarray(value, dtype=np.float64)
    if array.shape == (3,):
        return np.tile(array, (n_groups, 1))
    if array.shape != (n_groups, 3):
        raise TerraError(f"{what}: expected shape (3,) or ({n_groups}, 3), got {array.shape}")
    return array


def complete_extent(
    yaw: np.ndarray, centre: np.ndarray, size_xy: np.ndarray, min_extent: np.ndarray, viewpoint: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(yaw (G,), centre (G, 2), size (G, 2); the x axis along the longer side): the visible
    rectangles (yaw (G,) radians, centre, size along the box's x and y axes; metres, map frame)
    grown to at least `min_extent` (G, 3) (length, width, height; NaN = no prior) in xy, away
    from the viewer.

    A LiDAR sees the faces of an object that turn towards it: the faces nearest `viewpoint` (G, 3)
    (the sensor's position per group; None = unknown) are real, the hidden ones lie further away.
    So each side shorter than its prior keeps its near face and moves its far face away; a side
    whose slab holds the viewer (seen face-on) or without a viewpoint grows evenly about its
    centre. The longer visible side takes the prior length (the visible sides are never longer
    than their prior as this sorts both the same way): a car seen squarely from behind, only its
    back visible, is therefore turned across (a limit, noted in benchmarks/RESULTS.md)."""
    prior = np.sort(np.nan_to_num(min_extent[:, :2], nan=0.0), axis=1)[:, ::-1]  # (length, width)
    want = np.where((size_xy[:, 0] >= size_xy[:, 1])[:, None], prior, prior[:, ::-1])
    grow = np.clip(want - size_xy, 0.0, None)
    c, s = np.cos(yaw), np.sin(yaw)
    shift = np.zeros_like(grow)  # how far the centre moves along the box axes
    if viewpoint is not None:
        rel = viewpoint[:, :2] - centre
        local = np.column_stack([c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1]])
        side = np.where(np.abs(local) > size_xy / 2, -np.sign(local), 0.0)  # away from the viewer
        shift = side * grow / 2
    moved = centre + np.column_stack([c * shift[:, 0] - s * shift[:, 1], s * shift[:, 0] + c * shift[:, 1]])
    size = size_xy + grow
    swap = size[:, 1] > size[:, 0]  # keep the x axis along the longer side
    return wrap_half_turn(np.where(swap, yaw + np.pi / 2, yaw)), moved, np.where(swap[:, None], size[:, ::-1], size)


def fit_object_boxes(
    points: np.ndarray,
    groups: np.ndarray,
    ground_z: np.ndarray | None = None,
    context_yaw: np.ndarray | None = None,
    padding: float = 0.0,
    min_size: float = 0.05,
    lift: float = 0.15,
    prefer_context: float = 1.2,
    *,
    min_extent: ArrayLike | None = None,
    viewpoint: ArrayLike | None = None,
) -> list[OrientedBox]:
    """Boxes of objects standing on the ground, robust to partial views and to masks that bleed
    onto the ground. points: (n, 3) metres, map frame; groups: (n,) ids 0..G-1.

    - Footprint: from the points at least `lift` metres above the group's ground height
      `ground_z` (G,) (mask bleeding labels ground around an object as the object), unless fewer
      than three are; then from all of them.
    - Yaw: the one whose rectangle the footprint hugs closest (closeness_yaw; the hull's dominant
      edges, edge_yaw, turned real cars seen at an angle by up to 41 degrees), unless
      `context_yaw` (G,) (radians; NaN = none: the direction of the terrain strips around the
      object) gives a rectangle at most `prefer_context` times larger; a partial view often
      makes the minimum-area rectangle turn.
    - Height: from the ground (when below the lowest point) to the highest point.
    - `min_extent` ((3,) or (G, 3): length, width, height in metres; NaN = none), a prior on the
      object's size: a partial view is completed to at least that size, away from `viewpoint`
      ((3,) or (G, 3), map frame: where the sensor saw each object from; complete_extent), and up
      from its bottom. Without it the box spans what was seen.
    - `padding` (metres) is added to the footprint's sides and above the top (below the bottom
      too where the ground is unknown); then every size is at least `min_size` metres.
    """
    pts = np.asarray(points, dtype=np.float64)
    groups = np.asarray(groups, dtype=np.int64)
    order = np.argsort(groups, kind="stable")
    pts, groups = pts[order], groups[order]
    n_groups = int(groups[-1]) + 1 if len(groups) else 0
    ground = np.full(n_groups, -np.inf) if ground_z is None else np.asarray(ground_z, dtype=np.float64)
    high = pts[:, 2] >= ground[groups] + lift
    enough = np.bincount(groups[high], minlength=n_groups) >= 3
    foot = high | ~enough[groups]
    yaw, centre, size_xy = _edge_rectangles(pts[foot, :2], groups[foot], n_groups)
    if context_yaw is not None:
        yaw, centre, size_xy = _prefer_context(
            pts[foot, :2], groups[foot], np.asarray(context_yaw, dtype=np.float64), prefer_context, yaw, centre, size_xy
        )
    z_lo, z_hi = _z_extent(pts[:, 2], groups, n_groups, ground, padding)
    prior = _per_group(min_extent, n_groups, "min_extent")
    if prior is not None:
        yaw, centre, size_xy = complete_extent(
            yaw, centre, size_xy, prior, _per_group(viewpoint, n_groups, "viewpoint")
        )
        z_hi = np.maximum(z_hi, z_lo + np.nan_to_num(prior[:, 2], nan=0.0))
    sizes = np.maximum(np.column_stack([size_xy + padding, z_hi - z_lo]), min_size)
    centres = np.column_stack([centre, (z_lo + z_hi) / 2])
    return [OrientedBox(center=centres[g], size=sizes[g], yaw=float(yaw[g])) for g in range(n_groups)]
