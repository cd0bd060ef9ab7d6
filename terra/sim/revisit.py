"""A second visit of a simulated world (issue 26): the same site driven again, on the route reversed from
another start, its poses reported in another frame, after known changes.

Changes, drawn from `RevisitConfig.seed` near the route the revisit drives (it cannot see the rest): cars
moved along their own length or across it into a free stall (by 3 to 6 m), cars removed, cars added (a copy
of a parked car on free asphalt near the route), benches removed, square patches of lawn turned to dirt, and
fences put up across a sidewalk the route passes but does not drive along (end to end over the walkway's
width, turned across it). `revisit_world` returns the changed world and the ground truth of what changed, in
the first visit's map frame (the world frame): objects by instance id with their old and new centres, extent
and yaw, terrain patches with their polygon and area.

Blocked ground: a fence leaves the sidewalk's class in the terrain raster as it was (the ground is still
paved) but stands on it; the truth lists it as terrain {from: "sidewalk", to: "blocked"} over the cells of
the terrain raster (`TerrainGrid.resolution`, 0.25 m on the presets) that the fence's footprint (its posts'
width, 0.1 m) overlaps: a strip the walkway's width long and one cell wide where the fence stands inside one
row of cells, as it does here (its centre line is put on a cell's centre).

The revisit's frames report T_session_lidar = T_session_world @ T_world_lidar, where T_world_session is
`RevisitConfig.frame`; `RevisitTruth.to_json()` is what `terra sim --revisit` writes as revisit.json.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy.spatial import cKDTree  # pyright: ignore[reportAttributeAccessIssue]  # stubless compiled scipy module

from terra.datasets.ground_truth import ObjectBox
from terra.geometry import yaw_rotation
from terra.sim.builder import place_parts
from terra.sim.classes import class_id
from terra.sim.config import RevisitConfig
from terra.sim.objects import fence
from terra.sim.primitives import Primitives
from terra.sim.world import TerrainGrid, World

SEEN_RADIUS_M = 15.0  # a car or bench changed within this of the revisit's route: its LiDAR sees it


@dataclass
class RevisitTruth:
    """T_world_session (4x4, the first visit's map <- the revisit's frame) and the changes made:
    objects [{change, instance_id, class, from, to, distance}] (centres in metres, world frame) and terrain
    [{from, to, polygon (K, 2), area_m2}]."""

    T_world_session: np.ndarray
    objects: list[dict[str, Any]] = field(default_factory=list)
    terrain: list[dict[str, Any]] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        return {
            "frame": "centres and polygons in the first visit's map frame (the world frame)",
            "T_world_session": np.asarray(self.T_world_session).tolist(),
            "objects": self.objects,
            "terrain": self.terrain,
        }


def session_pose(config: RevisitConfig) -> np.ndarray:
    """T_world_session (4x4) of the revisit's frame: origin at (x, y) metres, turned yaw degrees."""
    x, y, yaw = config.frame
    T = np.eye(4)
    T[:3, :3], T[:2, 3] = yaw_rotation(np.radians(yaw)), [x, y]
    return T


def revisit_world(world: World, config: RevisitConfig) -> tuple[World, RevisitTruth]:
    """`world` after the changes of `config`, driven on its route reversed from `config.start_fraction`."""
    rng = np.random.default_rng([int(config.seed), world.seed, 26])
    route = rerouted(world.route, config.start_fraction)
    edit = _Edit(world, rng, route)
    truth = RevisitTruth(session_pose(config))
    cars = [o for o in world.objects if o.class_name == "car"]
    order = [c for c in (cars[int(i)] for i in rng.permutation(len(cars))) if edit.near(c.center)]
    untouched = []
    for car in order:  # cars with no free place ahead or behind stay where they are
        moved = edit.move(car, config.move_distance) if len(truth.objects) < config.cars_moved else None
        if moved is not None:
            truth.objects.append(moved)
        else:
            untouched.append(car)
    for car in untouched[: config.cars_removed]:
        truth.objects.append(edit.remove(car))
    for _ in range(config.cars_added):
        added = edit.add_copy(untouched[-1] if untouched else None)
        if added is not None:
            truth.objects.append(added)
    benches = [o for o in world.objects if o.class_name == "bench"]
    near_benches = [b for b in (benches[int(i)] for i in rng.permutation(len(benches))) if edit.near(b.center)]
    for bench in near_benches[: config.benches_removed]:
        truth.objects.append(edit.remove(bench))
    terrain = TerrainGrid(world.terrain.classes.copy(), world.terrain.origin, world.terrain.resolution)
    for _ in range(config.lawns_to_dirt):
        patch = _lawn_patch(terrain, edit, rng, config.patch_size)
        if patch is not None:
            truth.terrain.append(patch)
    for _ in range(config.fences_added):  # after the rest: a revisit without fences draws what it drew before
        fenced = _fence_across_sidewalk(terrain, edit, rng)
        if fenced is not None:
            truth.objects.append(fenced[0])
            truth.terrain.append(fenced[1])
    changed = replace(
        world,
        name=f"{world.name}-revisit{config.seed}",
        terrain=terrain,
        prims=edit.primitives(),
        objects=edit.objects,
        route=route,
        _tree=None,
        _raster_height=None,
    )
    return changed, truth


def rerouted(route: np.ndarray, start_fraction: float) -> np.ndarray:
    """The route (K, 2) reversed, starting `start_fraction` of its length from its (reversed) start."""
    back = np.asarray(route, dtype=np.float64)[::-1]
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(back, axis=0), axis=1))])
    s = start_fraction * cum[-1]
    k = int(np.searchsorted(cum, s, side="right"))
    if k >= back.shape[0]:
        return back[-2:]
    t = (s - cum[k - 1]) / max(cum[k] - cum[k - 1], 1e-12)
    return np.concatenate([[back[k - 1] + t * (back[k] - back[k - 1])], back[k:]])


class _Edit:
    """The world's shapes and objects as they are edited (shape rows kept, moved or dropped per instance)."""

    def __init__(self, world: World, rng: np.random.Generator, route: np.ndarray):
        self.world, self.rng = world, rng
        self.path = np.asarray(route, np.float64)
        self.route = cKDTree(route)  # the revisit's own route: a change elsewhere it would never see
        p = world.prims
        self.rows = [p.kind, p.center.copy(), p.half, p.yaw.copy(), p.class_id, p.instance_id.copy(), p.color]
        self.keep = np.ones(len(p), dtype=bool)
        self.extra: list[list[np.ndarray]] = []
        self.objects: list[ObjectBox] = list(world.objects)
        self.next_id = max([o.instance_id for o in world.objects] + [int(p.instance_id.max(initial=0))]) + 1

    def primitives(self) -> Primitives:
        columns = [np.concatenate([c[self.keep], *[e[i] for e in self.extra]]) for i, c in enumerate(self.rows)]
        return Primitives(*columns)

    def near(self, xy: np.ndarray, radius: float = SEEN_RADIUS_M) -> bool:
        """Whether `xy` (world frame, metres) lies within `radius` of the revisit's route."""
        return bool(self.route.query(np.asarray(xy, np.float64)[:2])[0] <= radius)

    def free(self, xy: np.ndarray, yaw: float, size: np.ndarray, ignore: int) -> bool:
        """Whether a footprint of `size` (length, width metres) turned `yaw` radians at `xy` (world frame)
        stands on asphalt and, grown by `MARGIN` metres, overlaps no other object's footprint. Rectangles, not
        discs: a car fits the empty stall beside another, which discs around both would refuse."""
        mine = _footprint(xy, yaw, size[:2] + 2 * MARGIN)
        for other in self.objects:
            if other.instance_id != ignore and _overlap(mine, _footprint(other.center[:2], other.yaw, other.size[:2])):
                return False
        probe = np.vstack([xy, _footprint(xy, yaw, size[:2])])
        return bool(np.all(self.world.terrain.class_at(probe) == class_id("asphalt")))

    def move(self, car: ObjectBox, distance: tuple[float, float], tries: int = 6) -> dict[str, Any] | None:
        """Move `car` by a distance drawn in `distance` (metres) along its length, or, where a full row leaves
        no room ahead or behind, across it (into a free stall of its row or another), if it lands free."""
        along = np.array([np.cos(car.yaw), np.sin(car.yaw)])
        across = np.array([-along[1], along[0]])
        for _ in range(tries):
            step = self.rng.uniform(*distance)
            signs = (1.0, -1.0) if self.rng.random() < 0.5 else (-1.0, 1.0)
            for offset in [sign * step * axis for axis in (along, across) for sign in signs]:
                if self.free(car.center[:2] + offset, car.yaw, car.size, car.instance_id):
                    return self._shift(car, offset)
        return None

    def _shift(self, car: ObjectBox, offset: np.ndarray) -> dict[str, Any]:
        """Move `car`'s shapes by `offset` (x, y metres), onto the ground there."""
        rows = self.rows[5] == car.instance_id
        ground = self.world.ground
        dz = float(ground.height(car.center[None, :2] + offset)[0] - ground.height(car.center[None, :2])[0])
        self.rows[1][rows] += [offset[0], offset[1], dz]
        new = replace(car, center=car.center + [offset[0], offset[1], dz])
        self.objects = [new if o.instance_id == car.instance_id else o for o in self.objects]
        return _change("moved", car, car.center, new.center)

    def remove(self, thing: ObjectBox) -> dict[str, Any]:
        self.keep &= self.rows[5] != thing.instance_id
        self.objects = [o for o in self.objects if o.instance_id != thing.instance_id]
        return _change("removed", thing, thing.center, None)

    def add_copy(self, car: ObjectBox | None, tries: int = 400) -> dict[str, Any] | None:
        """A copy of `car` parked, turned a random multiple of 90 degrees, on free asphalt within 20 m of the
        revisit's route (so the revisit sees it) and clear of it by a metre (not driven through)."""
        if car is None:
            return None
        x0, y0, x1, y1 = self.world.extent
        for _ in range(tries):
            xy = self.rng.uniform([x0, y0], [x1, y1])
            turn = float(self.rng.integers(4)) * np.pi / 2
            clear_of_route = not self.near(xy, float(np.hypot(*car.size[:2])) / 2 + 1.0)  # not driven through
            if not self.near(xy, 20.0) or not clear_of_route or not self.free(xy, car.yaw + turn, car.size, -1):
                continue
            return self._place_copy(car, xy, turn)
        return None

    def _place_copy(self, car: ObjectBox, xy: np.ndarray, turn: float) -> dict[str, Any]:
        rows = np.flatnonzero(self.rows[5] == car.instance_id)
        R = yaw_rotation(turn)[:2, :2]
        centre = self.rows[1][rows].copy()
        centre[:, :2] = (centre[:, :2] - car.center[:2]) @ R.T + xy
        ground = self.world.ground
        centre[:, 2] += float(ground.height(xy[None])[0] - ground.height(car.center[None, :2])[0])
        iid = self.next_id
        self.next_id += 1
        copy = [c[rows].copy() for c in self.rows]
        copy[1], copy[3], copy[5] = centre, copy[3] + turn, np.full(rows.size, iid, dtype=np.int32)
        self.extra.append(copy)
        z = car.center[2] + float(centre[0, 2] - self.rows[1][rows[0], 2])
        new = ObjectBox(iid, car.class_id, car.class_name, np.array([xy[0], xy[1], z]), car.size.copy(), car.yaw + turn)
        self.objects.append(new)
        return _change("added", new, None, new.center)

    def place(self, cls: str, parts: list, pose: tuple[float, float, float]) -> ObjectBox:
        """A new object of class `cls` from model `parts` at `pose` (x, y metres, yaw radians; world frame),
        on the ground there, with the next free instance id."""
        rows, thing = place_parts(parts, cls, self.next_id, pose, self.world.ground)
        self.next_id += 1
        p = Primitives.from_rows(rows)
        self.extra.append([p.kind, p.center, p.half, p.yaw, p.class_id, p.instance_id, p.color])
        self.objects.append(thing)
        return thing


MARGIN = 0.45  # metres kept clear around a moved or added car: the 0.9 m gap of a parking row (doors)


def _footprint(xy: np.ndarray, yaw: float, size: np.ndarray) -> np.ndarray:
    """(4, 2) corners (world frame, metres) of a `size` = (length, width) rectangle centred at `xy`, turned
    `yaw` radians."""
    half = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]]) * np.asarray(size[:2], np.float64) / 2
    return half @ yaw_rotation(yaw)[:2, :2].T + xy


def _overlap(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two convex polygons (K, 2) overlap: no edge normal of either separates them."""
    for poly in (a, b):
        for normal in (np.roll(poly, -1, axis=0) - poly) @ np.array([[0.0, -1.0], [1.0, 0.0]]):
            pa, pb = a @ normal, b @ normal
            if pa.max() <= pb.min() or pb.max() <= pa.min():
                return False
    return True


def _change(kind: str, thing: ObjectBox, before: np.ndarray | None, after: np.ndarray | None) -> dict[str, Any]:
    distance = None if before is None or after is None else float(np.linalg.norm((after - before)[:2]))
    return {
        "change": kind,
        "instance_id": int(thing.instance_id),
        "class": thing.class_name,
        "from": None if before is None else [round(float(v), 4) for v in before],
        "to": None if after is None else [round(float(v), 4) for v in after],
        "distance": None if distance is None else round(distance, 4),
        "extent": [round(float(v), 4) for v in thing.size],
        "yaw": round(float(thing.yaw), 4),
    }


def _lawn_patch(terrain: TerrainGrid, edit: _Edit, rng: np.random.Generator, size: float) -> dict[str, Any] | None:
    """Turn a size x size metre square of lawn (all grass, no object on it, within 8 m of the revisit's route)
    to dirt."""
    res = terrain.resolution
    cells = max(int(round(size / res)), 1)
    grass, dirt = class_id("grass"), class_id("dirt")
    centres = np.array([o.center[:2] for o in edit.objects]) if edit.objects else np.zeros((0, 2))
    h, w = terrain.classes.shape
    for _ in range(400):
        r, c = int(rng.integers(0, max(h - cells, 1))), int(rng.integers(0, max(w - cells, 1)))
        block = terrain.classes[r : r + cells, c : c + cells]
        x0, y0 = terrain.origin + np.array([c, r]) * res
        middle = np.array([x0, y0]) + cells * res / 2
        if not np.all(block == grass) or not edit.near(middle, 8.0):
            continue
        if centres.size and np.any(np.linalg.norm(centres - middle, axis=1) < cells * res):
            continue
        terrain.classes[r : r + cells, c : c + cells] = dirt
        x1, y1 = x0 + cells * res, y0 + cells * res
        polygon = [[x0, y0], [x1, y0], [x1, y1], [x0, y1]]
        return {
            "from": "grass",
            "to": "dirt",
            "polygon": [[round(float(a), 4), round(float(b), 4)] for a, b in polygon],
            "area_m2": round(float((cells * res) ** 2), 4),
        }
    return None


FENCE_NEAR_M = 12.0  # a fence within this of the revisit's route: its LiDAR sees the panel from the side
FENCE_CLEAR_M = 2.0  # and no nearer than this anywhere along it: the route passes it, not through it
FENCE_WIDTH_M = (1.5, 6.0)  # the sidewalk widths a fence closes (narrower is a kerb, wider a plaza)
FENCE_POST_M = 0.1  # its posts' side: the width of its footprint
FENCE_GAP_M = 1.0  # kept clear of every other object: a fence a hand's width from a car's bumper is one
# cluster of points with the car in change detection (points within 0.6 m join), and judged with it


def _fence_across_sidewalk(
    terrain: TerrainGrid, edit: _Edit, rng: np.random.Generator, tries: int = 400
) -> tuple[dict[str, Any], dict[str, Any]] | None:
    """Put up a fence across a walkway (a strip of sidewalk 1.5 to 6 m wide and at least twice as long)
    within `FENCE_NEAR_M` of the revisit's route and `FENCE_CLEAR_M` clear of it, `FENCE_GAP_M` clear of
    every object; the truth's added object and its blocked ground (None where no such place is found)."""
    sidewalk, res = class_id("sidewalk"), terrain.resolution
    for _ in range(tries):
        anchor = edit.path[int(rng.integers(len(edit.path)))] + rng.uniform(-FENCE_NEAR_M, FENCE_NEAR_M, 2)
        if terrain.class_at(anchor[None])[0] != sidewalk:
            continue
        crossing = _crossing(terrain, anchor)
        if crossing is None:
            continue
        centre, width, axis = crossing
        yaw = 0.0 if axis == 0 else np.pi / 2
        size = np.array([width, FENCE_POST_M])
        steps = np.linspace(-width / 2, width / 2, int(np.ceil(width / res)) + 1)
        line = centre + np.outer(steps, np.eye(2)[axis])  # points along the fence, a cell apart
        if not edit.near(centre, FENCE_NEAR_M) or any(edit.near(p, FENCE_CLEAR_M) for p in line):
            continue
        mine = _footprint(centre, yaw, size + 2 * FENCE_GAP_M)
        if any(_overlap(mine, _footprint(o.center[:2], o.yaw, o.size[:2])) for o in edit.objects):
            continue
        thing = edit.place("fence", fence(rng, length=width, post=FENCE_POST_M), (centre[0], centre[1], yaw))
        return _change("added", thing, None, thing.center), _blocked(terrain, centre, width, axis)
    return None


def _crossing(terrain: TerrainGrid, xy: np.ndarray) -> tuple[np.ndarray, float, int] | None:
    """Where a fence closes the walkway through `xy` (world frame, metres): its centre (2,) on the middle of
    the walkway's cross-section through `xy`'s cell, the walkway's width (metres, sidewalk cells end to end)
    and the grid axis it is crossed along (0: x, the walkway running north-south; 1: y); None unless the
    sidewalk there is a walkway: `FENCE_WIDTH_M` wide one way and at least twice that the other."""
    res, sidewalk = terrain.resolution, class_id("sidewalk")
    c, r = (int(v) for v in np.floor((np.asarray(xy) - terrain.origin) / res))
    runs = [_run(terrain.classes[r, :] == sidewalk, c), _run(terrain.classes[:, c] == sidewalk, r)]
    spans = [(hi - lo + 1) * res for lo, hi in runs]
    axis = int(np.argmin(spans))
    width = spans[axis]
    if not FENCE_WIDTH_M[0] <= width <= FENCE_WIDTH_M[1] or spans[1 - axis] < 2 * width:
        return None
    centre = terrain.origin + (np.array([c, r]) + 0.5) * res  # its own cell's centre along the walkway
    lo, hi = runs[axis]
    centre[axis] = terrain.origin[axis] + (lo + hi + 1) / 2 * res  # the walkway's middle across it
    return centre, float(width), axis


def _run(mask: np.ndarray, i: int) -> tuple[int, int]:
    """First and last index of the run of True in `mask` (1-D) that holds index `i`."""
    breaks = np.flatnonzero(~mask)
    before, after = breaks[breaks < i], breaks[breaks > i]
    return (int(before.max()) + 1 if before.size else 0), (int(after.min()) - 1 if after.size else mask.size - 1)


def _blocked(terrain: TerrainGrid, centre: np.ndarray, width: float, axis: int) -> dict[str, Any]:
    """The truth's blocked ground of a fence `width` metres long centred at `centre` across grid axis
    `axis`: the terrain raster's cells its footprint (`FENCE_POST_M` wide) overlaps, as their outline."""
    res = terrain.resolution
    half = np.full(2, FENCE_POST_M / 2)
    half[axis] = width / 2
    first = np.floor((centre - half - terrain.origin) / res + 1e-9)
    last = np.ceil((centre + half - terrain.origin) / res - 1e-9)
    (x0, y0), (x1, y1) = terrain.origin + first * res, terrain.origin + last * res
    polygon = [[x0, y0], [x1, y0], [x1, y1], [x0, y1]]
    return {
        "from": "sidewalk",
        "to": "blocked",
        "polygon": [[round(float(a), 4), round(float(b), 4)] for a, b in polygon],
        "area_m2": round(float((x1 - x0) * (y1 - y0)), 4),
    }
