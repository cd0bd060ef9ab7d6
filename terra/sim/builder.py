"""WorldBuilder: paints terrain, places objects on the ground and records regions and walkways.

Layout code (terra/sim/layout.py) calls it; `finish()` returns the World. Coordinates are map frame
(metres); yaw in radians about +z.
"""

from __future__ import annotations

import numpy as np
import shapely
from shapely.geometry import Polygon, box

from terra.datasets.ground_truth import NamedRegion, ObjectBox
from terra.geometry import yaw_rotation
from terra.sim.classes import CLASS_COLORS, class_id
from terra.sim.config import GeometryConfig
from terra.sim.geometry import Flight, build_steps
from terra.sim.heightfield import Heightfield, StepRaster
from terra.sim.objects import MODELS, Part
from terra.sim.primitives import CYLINDER, ELLIPSOID, Primitives
from terra.sim.route import plan_route
from terra.sim.world import TerrainGrid, World


class WorldBuilder:
    """Accumulates a world. Objects sit on the ground: the base of an object is the lowest ground
    height under its footprint (parts with `conform` follow the ground piece by piece)."""

    def __init__(
        self,
        name: str,
        seed: int,
        extent: tuple[float, float, float, float],
        resolution: float,
        ground: Heightfield,
        rng: np.random.Generator,
        fill: str = "grass",
    ) -> None:
        self.name, self.seed, self.extent = name, seed, extent
        self.rng = rng
        self.ground = ground
        x0, y0, x1, y1 = extent
        w = int(round((x1 - x0) / resolution))
        h = int(round((y1 - y0) / resolution))
        self.terrain = TerrainGrid(np.full((h, w), class_id(fill), np.uint8), np.array([x0, y0], float), resolution)
        self._rows: list[tuple] = []
        self.objects: list[ObjectBox] = []
        self.regions: list[NamedRegion] = []
        self.walkways: list[np.ndarray] = []
        self.waypoints: list[tuple[float, float]] = []
        self._occupied: dict[tuple[int, int], list[tuple[float, float, float]]] = {}  # cell -> (x, y, radius)
        self._next_instance = 1
        # Per object: its first and last row + 1, the points its base was taken at, whether it conforms.
        self._placements: list[tuple[int, int, np.ndarray, bool]] = []
        self.flights: list[Flight] = []

    # ----------------------------------------------------------------- terrain
    def _window(self, bounds: tuple[float, float, float, float]) -> tuple[slice, slice, np.ndarray, np.ndarray]:
        t = self.terrain
        h, w = t.classes.shape
        c0 = max(int(np.floor((bounds[0] - t.origin[0]) / t.resolution)), 0)
        c1 = min(int(np.ceil((bounds[2] - t.origin[0]) / t.resolution)), w)
        r0 = max(int(np.floor((bounds[1] - t.origin[1]) / t.resolution)), 0)
        r1 = min(int(np.ceil((bounds[3] - t.origin[1]) / t.resolution)), h)
        xs = t.origin[0] + (np.arange(c0, c1) + 0.5) * t.resolution
        ys = t.origin[1] + (np.arange(r0, r1) + 0.5) * t.resolution
        return slice(r0, r1), slice(c0, c1), xs, ys

    def paint(self, geometry, cls: str) -> None:
        """Set the terrain class of every cell whose centre lies in the shapely `geometry`."""
        if geometry.is_empty:
            return
        rows, cols, xs, ys = self._window(geometry.bounds)
        if xs.size == 0 or ys.size == 0:
            return
        gx, gy = np.meshgrid(xs, ys)
        inside = shapely.contains_xy(geometry, gx, gy)
        self.terrain.classes[rows, cols][inside] = class_id(cls)

    def paint_rect(self, x0: float, y0: float, x1: float, y1: float, cls: str) -> None:
        self.paint(box(min(x0, x1), min(y0, y1), max(x0, x1), max(y0, y1)), cls)

    def terrain_at(self, xy: np.ndarray) -> np.ndarray:
        return self.terrain.class_at(np.asarray(xy, float).reshape(-1, 2))

    # ----------------------------------------------------------------- objects
    def add(
        self, cls: str, x: float, y: float, yaw: float = 0.0, conform: bool = False, model: str | None = None, **params
    ) -> int:
        """Place one object of class `cls` (model `model` or the class's own) at (x, y) facing `yaw`.

        Returns its instance id. The ground-truth box is the box around all its parts, in the
        object's yawed frame.
        """
        parts = MODELS[model or cls](self.rng, **params)
        iid = self._next_instance
        self._next_instance += 1
        pose = (x, y, yaw)
        rows, thing = place_parts(parts, cls, iid, pose, self.ground, conform)
        # Where its base was read, for `_lift_objects` when the ground gets its steps at `finish`.
        self._placements.append(
            (len(self._rows), len(self._rows) + len(rows), base_probe(parts, pose, conform), conform)
        )
        if cls == "stairs":
            halves = np.array([p[2] for p in parts], float)
            top = max(c[2] + h[2] for _k, c, h, _y, _c in parts)
            self.flights.append(Flight(x, y, yaw, float(halves[:, 0].max()), float(halves[:, 1].max()), float(top)))
        self._rows.extend(rows)
        self.objects.append(thing)
        disc = (float(thing.center[0]), float(thing.center[1]), float(np.linalg.norm(thing.size[:2]) / 2))
        for cell in _cells(*disc):
            self._occupied.setdefault(cell, []).append(disc)
        return iid

    def is_free(self, x: float, y: float, radius: float, on: tuple[str, ...] = ("grass",)) -> bool:
        """True when a disc of `radius` at (x, y) lies on the given terrain and clear of objects."""
        ang = np.linspace(0, 2 * np.pi, 8, endpoint=False)
        probe = np.concatenate([[[x, y]], np.stack([x + radius * np.cos(ang), y + radius * np.sin(ang)], 1)])
        allowed = np.isin(self.terrain_at(probe), [class_id(c) for c in on])
        if not allowed.all():
            return False
        for cell in _cells(x, y, radius):
            for ox, oy, r in self._occupied.get(cell, ()):
                if (ox - x) ** 2 + (oy - y) ** 2 < (r + radius) ** 2:
                    return False
        return True

    def scatter(
        self,
        cls: str,
        area,
        count: int,
        radius: float,
        on: tuple[str, ...] = ("grass",),
        tries: int = 40,
        yaw: float | None = None,
        **params,
    ) -> list[int]:
        """Place up to `count` objects at random free spots inside the shapely polygon `area`."""
        ids = []
        x0, y0, x1, y1 = area.bounds
        for _ in range(count * tries):
            if len(ids) >= count:
                break
            x, y = self.rng.uniform(x0, x1), self.rng.uniform(y0, y1)
            if not shapely.contains_xy(area, x, y) or not self.is_free(x, y, radius, on):
                continue
            ids.append(self.add(cls, x, y, self.rng.uniform(0, 2 * np.pi) if yaw is None else yaw, **params))
        return ids

    # ----------------------------------------------------------------- regions and route
    def region(self, name: str, description: str, polygon) -> None:
        """A named region: a shapely polygon (or a list of (x, y) corners) and one sentence."""
        poly = polygon if isinstance(polygon, Polygon) else Polygon(polygon)
        coords = np.asarray(poly.exterior.coords)[:-1]
        self.regions.append(NamedRegion(name, description, coords.astype(float)))

    def walkway(self, *points: tuple[float, float]) -> None:
        """A polyline the robot may drive along (it must lie on sidewalk, asphalt or dirt)."""
        self.walkways.append(np.asarray(points, float))

    def visit(self, *points: tuple[float, float]) -> None:
        """Points the route passes through, in order (each on a walkway)."""
        self.waypoints.extend((float(x), float(y)) for x, y in points)

    def finish(self, route_length: float | None = None, geometry: GeometryConfig | None = None) -> World:
        """The World, with the route cut to `route_length` metres (None: whole) and, with `geometry`,
        the ground's step offsets (terra/sim/geometry.py) under the objects, which rise with them."""
        route = plan_route(self.walkways, self.waypoints, route_length)
        if geometry is not None:
            self.ground.steps = build_steps(self.terrain, self.walkways, self.flights, self._occupied_cells(), geometry)
            self._lift_objects(self.ground.steps)
        return World(
            self.name,
            self.seed,
            self.extent,
            self.ground,
            self.terrain,
            Primitives.from_rows(self._rows),
            self.objects,
            self.regions,
            route,
        )

    def _occupied_cells(self, margin: float = 1.0) -> np.ndarray:
        """(H, W) bool: terrain cells within `margin` metres of a placed object's disc."""
        xs, ys = self.terrain.cell_centres()
        out = np.zeros(self.terrain.classes.shape, bool)
        discs = {disc for cell in self._occupied.values() for disc in cell}
        for x, y, r in discs:
            cols = np.flatnonzero(np.abs(xs - x) <= r + margin)
            rows = np.flatnonzero(np.abs(ys - y) <= r + margin)
            if cols.size and rows.size:
                d = np.hypot(xs[cols][None, :] - x, ys[rows][:, None] - y)
                out[rows[:, None], cols[None, :]] |= d <= r + margin
        return out

    def _lift_objects(self, steps: StepRaster) -> None:
        """Raise every placed object by the step offset under it, as `add` based it: a conforming
        object's parts each by the offset under them, any other by the lowest under its footprint."""
        for index, (start, stop, probe, conform) in enumerate(self._placements):
            lift = steps.at(probe)
            lifts = lift if conform else np.full(stop - start, float(lift.min()))
            for row, dz in zip(range(start, stop), lifts):
                kind, (cx, cy, cz), *rest = self._rows[row]
                self._rows[row] = (kind, (cx, cy, cz + float(dz)), *rest)
            box = self.objects[index]
            box.center[2] += float(lifts.min())


def place_parts(
    parts: list[Part], cls: str, iid: int, pose: tuple[float, float, float], ground: Heightfield, conform: bool = False
) -> tuple[list[tuple], ObjectBox]:
    """An object's shape rows (kind, centre, half sizes, yaw, class id, instance id, colour; map frame) and
    its ground-truth box, for `parts` in its own frame placed at `pose` = (x, y metres, yaw radians) on the
    ground: each part on the ground under it (`conform`), else all on the lowest ground under the
    footprint's corners and centre, so no object floats on a slope."""
    x, y, yaw = pose
    cid = class_id(cls)
    R = yaw_rotation(yaw)
    centres = np.array([p[1] for p in parts], float)
    halves = np.array([p[2] for p in parts], float)
    world_xy = centres[:, :2] @ R[:2, :2].T + [x, y]
    heights = ground.height(base_probe(parts, pose, conform))
    base = heights if conform else np.full(len(parts), float(heights.min()))
    rows = []
    for (kind, c, h, pyaw, color), wxy, b in zip(parts, world_xy, base):
        rgb = CLASS_COLORS[cid] if color is None else color
        rows.append((kind, (wxy[0], wxy[1], b + c[2]), h, yaw + pyaw, cid, iid, tuple(int(v) for v in rgb)))
    # Ground-truth box in the object's frame: part extents (yawed parts use |R| h).
    ext = []
    for kind, _c, h, pyaw, _ in parts:
        if kind in (CYLINDER, ELLIPSOID) and h[0] == h[1]:
            ext.append(np.array([h[0], h[1]]))
        else:
            ext.append(np.abs(yaw_rotation(pyaw)[:2, :2]) @ np.array(h[:2]))
    lo_xy = (centres[:, :2] - np.array(ext)).min(axis=0)
    hi_xy = (centres[:, :2] + np.array(ext)).max(axis=0)
    z_lo = (base + centres[:, 2] - halves[:, 2]).min()
    z_hi = (base + centres[:, 2] + halves[:, 2]).max()
    c_world = R[:2, :2] @ ((lo_xy + hi_xy) / 2) + [x, y]
    size = np.array([hi_xy[0] - lo_xy[0], hi_xy[1] - lo_xy[1], z_hi - z_lo])
    centre = np.array([c_world[0], c_world[1], (z_lo + z_hi) / 2])
    return rows, ObjectBox(iid, cid, cls, centre, size, float(_wrap(yaw)))


def base_probe(parts: list[Part], pose: tuple[float, float, float], conform: bool) -> np.ndarray:
    """Map-frame x, y (metres) where an object's base is read from the ground: under each part's centre
    (`conform`), else at the corners and the centre of its parts' footprint, for `parts` in its own frame
    placed at `pose` = (x, y metres, yaw radians)."""
    x, y, yaw = pose
    R = yaw_rotation(yaw)[:2, :2]
    centres = np.array([p[1] for p in parts], float)
    if conform:
        return centres[:, :2] @ R.T + [x, y]
    halves = np.array([p[2] for p in parts], float)
    lo = (centres[:, :2] - halves[:, :2]).min(axis=0)
    hi = (centres[:, :2] + halves[:, :2]).max(axis=0)
    return np.array([[lo[0], lo[1]], [lo[0], hi[1]], [hi[0], lo[1]], [hi[0], hi[1]], [0, 0]]) @ R.T + [x, y]


_CELL = 8.0  # metres; spatial hash of placed objects


def _cells(x: float, y: float, r: float) -> list[tuple[int, int]]:
    """Hash cells a disc's bounding square touches."""
    i0, i1 = int(np.floor((x - r) / _CELL)), int(np.floor((x + r) / _CELL))
    j0, j1 = int(np.floor((y - r) / _CELL)), int(np.floor((y + r) / _CELL))
    return [(i, j) for i in range(i0, i1 + 1) for j in range(j0, j1 + 1)]


def _wrap(angle: float) -> float:
    """Angle in (-pi, pi]."""
    a = (angle + np.pi) % (2 * np.pi) - np.pi
    return np.pi if a == -np.pi else a
