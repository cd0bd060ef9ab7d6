"""Terrain-aware navigation on the places layer (paper, Phase 3, "Navigation").

Terrain preferences as edge costs, in metres-equivalent:

    cost(u, v) = length(u, v) x (1 + (penalty[terrain u] + penalty[terrain v]) / 2)

- length(u, v) is the edge's length along the graph: its weight, the length of the GVD path (or
  grid path) between the two places in metres, climb included (bridges carry their penalty),
  never less than the straight-line distance between them. A GVD path follows the middle of the
  terrain and steps from cell to cell (one step of 1 or sqrt(2) cells), so it is a few per cent
  longer than the straight segment between its places even on a straight strip.
- penalty[t] is the explicit `penalties` value for terrain t (>= 0). Terrains in `prefer` get 0
  (preference wins over an explicit penalty, as in the reference's task files). When `prefer` is
  not empty, every other terrain without an explicit penalty gets `default_penalty`: with the
  default 5.0 (terra.tasks.config.DEFAULT_PENALTY, chosen on a validation scene), a metre off the
  preferred terrains costs as much as six metres on them.
- Places on `forbid` terrains are removed with all their edges: a path never touches them, and
  when none remains the planner raises NoPathError (exit code 3) rather than crossing them.

Penalties are non-negative, so every cost is at least the straight-line length and the A*
straight-line heuristic is admissible: the plan is the cheapest path under these costs.

A plan reports both lengths: `length_m`, the straight segments between its waypoints, and
`edge_length_m`, the lengths along the graph that the cost uses. Each edge's length is split half
and half between its two places' terrains (`edge_length_by_terrain`), so that

    cost = sum over terrains t of edge_length_by_terrain[t] x (1 + penalty[t])

exactly; with no penalty on the path's terrains, cost = edge_length_m.

A plan also says which of its steps only a bridge joins (`bridges`, `bridge_length_m`): a bridge
links two parts of the graph that nothing else links, over ground the map did not join (unobserved,
or cut by obstacles); what lies on it is unknown, a robot's limits included.

A robot profile (terra.tasks.robot, `terra plan --robot`) removes the edges whose step or slope,
in the direction of travel, is beyond the robot, those that cross more unobserved ground in one
stretch than it accepts, and the places too narrow for it, and multiplies the cost of a sloped
edge by 1 + slope_cost x (its slope / the limit); the graph itself is the same for every robot.
With ground geometry in the graph, a plan reports the largest step, the steepest climb and
descent and the longest stretch over unobserved ground along it (`PathGround`).

Goals named by a task: every object retrieved for it is a candidate, tried best score first; a
candidate is skipped when no allowed place lies near it or no path reaches that place, and the
plan says which were skipped and why (`plan_to_objects`). No path exists only when every
candidate fails.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Generic, Protocol, TypeVar

import numpy as np

from terra.errors import NoPathError, TerraError
from terra.graph.scene_graph import (
    EDGE_BRIDGE,
    EDGE_GEOMETRY_COLUMNS,
    EDGE_GEOMETRY_FORWARDS,
    EDGE_GEOMETRY_REVERSED,
    SceneGraph,
)
from terra.tasks.astar import astar
from terra.tasks.config import DEFAULT_PENALTY
from terra.tasks.robot import RobotProfile

TerrainRef = str | int
# Penalties per terrain name or index (a dict of names alone is not a Mapping[TerrainRef, ...]).
Penalties = Mapping[str, float] | Mapping[int, float] | Mapping[TerrainRef, float]


def resolve_terrain(terrain_classes: list[str], ref: TerrainRef) -> int:
    """Index of a terrain given by name (case-insensitive) or by index (an int or digit string)."""
    names = [t.lower() for t in terrain_classes]
    if isinstance(ref, (int, np.integer)) or (isinstance(ref, str) and ref.strip().isdigit()):
        index = int(ref)
        if 0 <= index < len(terrain_classes):
            return index
        raise TerraError(
            f"terrain index {index} is out of range; "
            f"the graph has {len(terrain_classes)} terrains: {', '.join(terrain_classes)}"
        )
    key = str(ref).strip().lower()
    if key not in names:
        raise TerraError(f"unknown terrain {str(ref)!r}; expected one of: {', '.join(terrain_classes)}")
    return names.index(key)


@dataclass(frozen=True)
class TerrainCosts:
    """Per terrain class: penalty (T,) >= 0 and forbidden (T,) bool. See the module docstring."""

    penalty: np.ndarray
    forbidden: np.ndarray

    @classmethod
    def from_preferences(
        cls,
        terrain_classes: list[str],
        prefer: Iterable[TerrainRef] = (),
        penalties: Penalties | None = None,
        forbid: Iterable[TerrainRef] = (),
        default_penalty: float = DEFAULT_PENALTY,
    ) -> TerrainCosts:
        n = len(terrain_classes)
        preferred = {resolve_terrain(terrain_classes, t) for t in prefer}
        forbidden_set = {resolve_terrain(terrain_classes, t) for t in forbid}
        both = preferred & forbidden_set
        if both:
            raise TerraError(f"terrain {terrain_classes[min(both)]!r} is both preferred and forbidden")
        if default_penalty < 0:
            raise TerraError(f"default penalty must be >= 0, got {default_penalty}")
        penalty = np.full(n, default_penalty if preferred else 0.0)
        for ref, value in (penalties or {}).items():
            index = resolve_terrain(terrain_classes, ref)
            value = float(value)
            if not np.isfinite(value) or value < 0:
                raise TerraError(
                    f"penalty for terrain {terrain_classes[index]!r} must be a finite number >= 0, got {value}; "
                    "use --forbid to exclude it"
                )
            penalty[index] = value
        penalty[list(preferred)] = 0.0
        forbidden = np.zeros(n, dtype=bool)
        forbidden[list(forbidden_set)] = True
        return cls(penalty=penalty, forbidden=forbidden)


@dataclass
class CostGraph:
    """The places graph under one set of terrain costs, as directed CSR arrays (both directions of
    every allowed edge; duplicate edges keep their cheapest cost)."""

    indptr: np.ndarray
    indices: np.ndarray
    cost: np.ndarray
    allowed: np.ndarray  # (P,) bool: place not on forbidden terrain
    min_factor: float = 1.0  # every cost >= min_factor x straight-line length (A* heuristic scale)
    limits: str = ""  # what a robot profile removed, for the no-path message

    @classmethod
    def build(cls, graph: SceneGraph, costs: TerrainCosts, robot: RobotProfile | None = None) -> CostGraph:
        """The cost graph of `graph` under `costs` and, when given, a robot profile's limits on
        steps, slopes and width (terra.tasks.robot; TerraError when the graph has no ground
        geometry to check them against)."""
        n = len(graph.places)
        terrain = np.asarray(graph.places.terrain, dtype=np.int64)
        allowed = ~costs.forbidden[terrain] if n else np.zeros(0, dtype=bool)
        i, j, length = edge_lengths(graph)
        cost = length * (1.0 + (costs.penalty[terrain[i]] + costs.penalty[terrain[j]]) / 2)
        # Both directions of every edge: a robot may climb what it cannot descend.
        src, dst, cost = np.concatenate([i, j]), np.concatenate([j, i]), np.concatenate([cost, cost])
        keep = src != dst
        if robot is not None:
            allowed = allowed & _wide_enough(graph, robot)
            factor, legal = robot.edge_rules(_edge_geometry(graph, robot))
            cost, keep = cost * factor, keep & legal
        keep &= allowed[src] & allowed[dst]
        src, dst, cost = src[keep], dst[keep], cost[keep]
        # One entry per directed pair (the cheapest of duplicates), in CSR order: sorting packed
        # int64 keys is much faster than a multi-key lexsort.
        key = src * n + dst
        order = np.argsort(key, kind="stable")
        key, src, dst, cost = key[order], src[order], dst[order], cost[order]
        starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]]) if len(key) else np.zeros(0, dtype=np.int64)
        src, dst = src[starts], dst[starts]
        cost = np.minimum.reduceat(cost, starts) if len(starts) else cost
        indptr = np.concatenate([[0], np.cumsum(np.bincount(src, minlength=n))]).astype(np.int64)
        # Every allowed edge costs at least (1 + smallest penalty among allowed terrains) x its
        # straight-line length (a robot's factors are >= 1), which scales the A* heuristic without
        # losing admissibility.
        present = np.unique(terrain[allowed]) if n else np.zeros(0, dtype=np.int64)
        min_factor = 1.0 + float(costs.penalty[present].min()) if present.size else 1.0
        limits = robot.limits() if robot is not None else ""
        return cls(indptr=indptr, indices=dst, cost=cost, allowed=allowed, min_factor=min_factor, limits=limits)


def _wide_enough(graph: SceneGraph, robot: RobotProfile) -> np.ndarray:
    """(P,) bool: places whose passage is at least the robot's width: twice their room (metres to
    the nearest obstacle, terra.graph.room), or of their clearance where the graph does not record
    the room (a bundle written before it was)."""
    room = np.asarray(graph.places.room, dtype=np.float64)
    half = np.where(np.isfinite(room), room, np.asarray(graph.places.clearance, dtype=np.float64))
    return 2.0 * half >= robot.min_width


def _edge_geometry(graph: SceneGraph, robot: RobotProfile) -> np.ndarray:
    """The graph's (E, 5) edge geometry; TerraError when it has none to check the robot against."""
    if len(graph.place_edges) and not graph.has_edge_geometry:
        raise TerraError(
            f"the scene graph has no ground geometry (steps, slopes) to check robot {robot.name!r} against; "
            "rebuild it with `terra build` (build.ground.layers: true)"
        )
    return graph.place_edge_geometry.reshape(-1, len(EDGE_GEOMETRY_COLUMNS))


def edge_lengths(graph: SceneGraph) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every place edge's endpoints (E,), (E,) and its length along the graph (E,) metres: its
    weight, at least the straight-line distance between its places (the module docstring)."""
    edges = np.asarray(graph.place_edges, dtype=np.int64).reshape(-1, 2)
    pos = np.asarray(graph.places.position, dtype=np.float64)
    i, j = edges[:, 0], edges[:, 1]
    straight = np.linalg.norm(pos[i] - pos[j], axis=1)
    return i, j, np.maximum(np.asarray(graph.place_edge_weight, dtype=np.float64), straight)


def step_lengths(graph: SceneGraph, places: np.ndarray) -> np.ndarray:
    """(n - 1,) metres: the length along the graph of each step of a path of places (n,), the
    shortest of the edges joining its two places (the one the cost graph keeps; NaN where no edge
    joins them)."""
    _, _, length = edge_lengths(graph)
    key, wanted = _pair_keys(graph, places)
    hit = np.isin(key, wanted)  # only the path's own edges go through Python
    shortest: dict[int, float] = {}
    for k, value in zip(key[hit].tolist(), length[hit].tolist()):
        shortest[k] = min(value, shortest.get(k, np.inf))
    return np.array([shortest.get(k, np.nan) for k in wanted.tolist()], dtype=np.float64)


COST_GRAPHS = 16  # cost graphs kept per scene graph (one per set of terrain preferences)


class CostGraphs:
    """The cost graphs of one scene graph under the sets of terrain preferences asked for lately
    (the last COST_GRAPHS), safe to share between threads. A cost graph asked for a second time
    gets A*'s adjacency lists prepared: from then on it is worth them."""

    def __init__(self) -> None:
        self._graphs: OrderedDict[tuple, CostGraph] = OrderedDict()
        self._searched: set[tuple] = set()  # cost graphs fetched more than once
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self._graphs)

    def get(self, graph: SceneGraph, costs: TerrainCosts, robot: RobotProfile | None = None) -> CostGraph:
        key = (id(graph), costs.penalty.tobytes(), costs.forbidden.tobytes(), robot.key() if robot else None)
        with self._lock:
            cached = self._graphs.get(key)
            reused = False
            if cached is not None:
                self._graphs.move_to_end(key)
                reused = key in self._searched
                self._searched.add(key)
        if cached is not None:
            if not reused:
                from terra.tasks.astar import prepare_adjacency

                prepare_adjacency(cached.indptr, cached.indices, cached.cost)
            return cached
        built = CostGraph.build(graph, costs, robot)
        with self._lock:
            self._graphs[key] = built
            while len(self._graphs) > COST_GRAPHS:
                self._searched.discard(self._graphs.popitem(last=False)[0])
        return built


@dataclass
class PathPlan:
    """A planned path. places: (n,) place indices from start to goal; waypoints: (n, 3) their
    positions (metres, map frame); length_m: sum of straight segments between waypoints;
    length_by_terrain: metres per terrain name (each segment split half and half between its
    endpoints' terrains); cost: the A* cost under the terrain preferences; edge_length_m and
    edge_length_by_terrain: the same for the lengths along the graph the cost is made of (module
    docstring: cost = sum of edge_length_by_terrain[t] x (1 + penalty[t]))."""

    places: np.ndarray
    waypoints: np.ndarray
    length_m: float
    length_by_terrain: dict[str, float]
    cost: float
    terrain: list[str]
    edge_length_m: float = 0.0
    edge_length_by_terrain: dict[str, float] = field(default_factory=dict)
    ground: PathGround | None = None
    bridges: int = 0  # steps only a bridge edge joins (module docstring)
    bridge_length_m: float = 0.0  # their straight length, metres

    @property
    def start(self) -> int:
        return int(self.places[0])

    @property
    def goal(self) -> int:
        return int(self.places[-1])

    def to_json(self) -> dict[str, Any]:
        return {
            "start_place": self.start,
            "goal_place": self.goal,
            "places": [int(p) for p in self.places],
            "waypoints": [[round(float(v), 4) for v in w] for w in self.waypoints],
            "terrain": list(self.terrain),
            "length_m": round(self.length_m, 4),
            "length_by_terrain": {k: round(v, 4) for k, v in self.length_by_terrain.items()},
            "edge_length_m": round(self.edge_length_m, 4),
            "edge_length_by_terrain": {k: round(v, 4) for k, v in self.edge_length_by_terrain.items()},
            "cost": round(self.cost, 4),
            "ground": self.ground.to_json() if self.ground is not None else None,
            "bridges": self.bridges,
            "bridge_length_m": round(self.bridge_length_m, 4),
        }


@dataclass(frozen=True)
class PathGround:
    """The ground a path crosses (terra.graph.ground, from its edges' geometry): the largest step
    (metres), the steepest climb and descent in the direction of travel (degrees), the longest
    stretch of one edge over ground the map never observed (metres) and the steepest slope across
    its way (degrees) (the last two None where the graph does not record them)."""

    max_step_m: float
    max_climb_deg: float
    max_descent_deg: float
    max_unobserved_m: float | None = None
    max_cross_slope_deg: float | None = None

    @property
    def max_slope_deg(self) -> float:
        return max(self.max_climb_deg, self.max_descent_deg)

    def to_json(self) -> dict[str, float | None]:
        unobserved = None if self.max_unobserved_m is None else round(self.max_unobserved_m, 3)
        return {
            "max_step_m": round(self.max_step_m, 4),
            "max_climb_deg": round(self.max_climb_deg, 3),
            "max_descent_deg": round(self.max_descent_deg, 3),
            "max_slope_deg": round(self.max_slope_deg, 3),
            "max_unobserved_m": unobserved,
            "max_cross_slope_deg": None if self.max_cross_slope_deg is None else round(self.max_cross_slope_deg, 3),
        }


def path_ground(graph: SceneGraph, places: np.ndarray) -> PathGround | None:
    """The ground a path of places (n,) crosses, None when the graph has no edge geometry. Each
    step uses an edge joining its two places (its geometry read in the direction of travel);
    steps without one count as level."""
    if not graph.has_edge_geometry or len(places) < 2:
        return None
    edges = np.asarray(graph.place_edges, dtype=np.int64).reshape(-1, 2)
    n = max(len(graph.places), 1)
    keys = edges[:, 0] * n + edges[:, 1]
    order = np.argsort(keys, kind="stable")
    a, b = np.asarray(places[:-1], dtype=np.int64), np.asarray(places[1:], dtype=np.int64)
    geometry = np.asarray(graph.place_edge_geometry, dtype=np.float64)
    rows = np.zeros((len(a), len(EDGE_GEOMETRY_COLUMNS)))
    for wanted, columns in ((b * n + a, EDGE_GEOMETRY_REVERSED), (a * n + b, EDGE_GEOMETRY_FORWARDS)):  # forwards wins
        at = np.minimum(np.searchsorted(keys[order], wanted), len(keys) - 1)
        hit = keys[order][at] == wanted
        rows[hit] = geometry[order[at[hit]]][:, columns]
    # NaN: a bundle that does not record the column
    unobserved, cross = (float(np.nanmax(c)) if np.isfinite(c).any() else None for c in (rows[:, 3], rows[:, 4]))
    return PathGround(float(rows[:, 0].max()), float(rows[:, 1].max()), float(rows[:, 2].max()), unobserved, cross)


def _pair_keys(graph: SceneGraph, places: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Undirected keys (low x P + high) of every place edge (E,) and of each step of a path of
    places (n,): (n - 1,)."""
    edges = np.asarray(graph.place_edges, dtype=np.int64).reshape(-1, 2)
    n = max(len(graph.places), 1)
    places = np.asarray(places, dtype=np.int64)
    key = edges.min(axis=1) * n + edges.max(axis=1)
    wanted = np.minimum(places[:-1], places[1:]) * n + np.maximum(places[:-1], places[1:])
    return key, wanted


def bridge_steps(graph: SceneGraph, places: np.ndarray) -> np.ndarray:
    """(n - 1,) bool: the steps of a path of places (n,) that no edge but a bridge (EDGE_BRIDGE)
    joins."""
    key, wanted = _pair_keys(graph, places)
    bridge = np.asarray(graph.place_edge_kind) == EDGE_BRIDGE
    return np.isin(wanted, key[bridge]) & ~np.isin(wanted, key[~bridge])


def path_from_places(graph: SceneGraph, places: list[int], cost: float) -> PathPlan:
    """A PathPlan for a node sequence: waypoints, lengths (straight and along the graph) and their
    terrain breakdown."""
    idx = np.asarray(places, dtype=np.int64)
    waypoints = np.asarray(graph.places.position, dtype=np.float64)[idx]
    terrain = np.asarray(graph.places.terrain, dtype=np.int64)[idx]
    segment = np.linalg.norm(np.diff(waypoints, axis=0), axis=1)
    along = step_lengths(graph, idx)
    along = np.where(np.isfinite(along), along, segment)
    bridged = bridge_steps(graph, idx)
    return PathPlan(
        idx,
        waypoints,
        float(segment.sum()),
        _by_terrain(graph.terrain_classes, terrain, segment),
        float(cost),
        [graph.terrain_classes[t] for t in terrain],
        float(along.sum()),
        _by_terrain(graph.terrain_classes, terrain, along),
        path_ground(graph, idx),
        int(bridged.sum()),
        float(segment[bridged].sum()),
    )


def _by_terrain(names: list[str], terrain: np.ndarray, step: np.ndarray) -> dict[str, float]:
    """Metres per terrain name of a path's steps (n - 1,), each split half and half between the
    terrains (n,) of its two places."""
    per_terrain = np.zeros(len(names))
    np.add.at(per_terrain, terrain[:-1], step / 2)
    np.add.at(per_terrain, terrain[1:], step / 2)
    return {names[t]: float(per_terrain[t]) for t in np.flatnonzero(per_terrain > 0)}


def _check_place(graph: SceneGraph, place: int, role: str) -> int:
    place = int(place)
    if not 0 <= place < len(graph.places):
        raise TerraError(f"{role} place {place} does not exist; the graph has places 0..{len(graph.places) - 1}")
    return place


def plan_path(
    graph: SceneGraph,
    start_place: int,
    goal_place: int,
    prefer: Iterable[TerrainRef] = (),
    penalties: Penalties | None = None,
    forbid: Iterable[TerrainRef] = (),
    default_penalty: float = DEFAULT_PENALTY,
    robot: RobotProfile | None = None,
) -> PathPlan:
    """The cheapest path between two places under terrain preferences (see the module docstring)
    and, when given, a robot profile's limits and slope cost (terra.tasks.robot).

    Terrains are names (case-insensitive) or indices into graph.terrain_classes. Raises TerraError
    for unknown terrains or places and NoPathError when the goal cannot be reached without
    forbidden terrain.
    """
    start = _check_place(graph, start_place, "start")
    goal = _check_place(graph, goal_place, "goal")
    costs = TerrainCosts.from_preferences(graph.terrain_classes, prefer, penalties, forbid, default_penalty)
    cost_graph = CostGraph.build(graph, costs, robot)
    return plan_on(graph, cost_graph, start, goal)


def plan_on(graph: SceneGraph, cost_graph: CostGraph, start: int, goal: int) -> PathPlan:
    """A* between two places on a prepared CostGraph (reuse it for many plans)."""
    names = graph.terrain_classes
    terrain = graph.places.terrain
    for place, role in ((start, "start"), (goal, "goal")):
        if not cost_graph.allowed[place]:
            raise NoPathError(f"no path: the {role} place {place} is on forbidden terrain {names[terrain[place]]!r}")
    result = astar(
        cost_graph.indptr,
        cost_graph.indices,
        cost_graph.cost,
        graph.places.position,
        start,
        goal,
        heuristic_scale=cost_graph.min_factor,
    )
    if result is None:
        forbidden = sorted({names[t] for t in terrain[~cost_graph.allowed] if t >= 0})
        if cost_graph.limits:
            why = f" for {cost_graph.limits}"
        elif forbidden:
            why = f" without crossing forbidden terrain ({', '.join(forbidden)})"
        else:
            why = " (the places graph is disconnected)"
        raise NoPathError(
            f"no path from place {start} ({names[terrain[start]]}) to place {goal} ({names[terrain[goal]]}){why}"
        )
    places, cost = result
    return path_from_places(graph, places, cost)


# ---------------------------------------------------------------- goals from retrieved objects


class GoalObject(Protocol):
    """What planning reads from a retrieved object (terra.tasks.retrieval.FoundObject): its label,
    score, centre (3,) metres in the map frame and linked (nearest) place."""

    label: str
    score: float
    center: np.ndarray
    place: int


def nearest_allowed_place(graph: SceneGraph, xy: np.ndarray, allowed: np.ndarray, max_distance: float = np.inf) -> int:
    """The allowed place nearest (2-D) to xy (metres, map frame), or -1 when none lies within
    max_distance metres."""
    candidates = np.flatnonzero(allowed)
    if candidates.size == 0:
        return -1
    d = np.linalg.norm(graph.places.position[candidates, :2] - np.asarray(xy, dtype=np.float64)[:2], axis=1)
    best = int(np.argmin(d))
    return int(candidates[best]) if d[best] <= max_distance else -1


def approach_place(graph: SceneGraph, obj: GoalObject, allowed: np.ndarray, radius: float) -> tuple[int, str]:
    """(place, "") where the robot approaches `obj`: its own place when allowed, else the nearest
    allowed place within `radius` metres of its centre; (-1, why) when there is none."""
    if 0 <= obj.place < len(allowed) and allowed[obj.place]:
        return int(obj.place), ""
    place = nearest_allowed_place(graph, obj.center, allowed, radius)
    if place >= 0:
        return place, ""
    if 0 <= obj.place < len(allowed):
        terrain = graph.terrain_classes[int(graph.places.terrain[obj.place])]
        return (
            -1,
            f"its place {obj.place} is on forbidden terrain {terrain!r} and no allowed place lies within {radius:g} m",
        )
    return -1, f"no allowed place lies within {radius:g} m"


@dataclass
class SkippedGoal:
    """A goal candidate that was not planned to, and why."""

    object: GoalObject
    approach_place: int
    reason: str

    def to_json(self) -> dict[str, Any]:
        o = self.object
        return {
            "label": o.label,
            "score": round(float(o.score), 6),
            "center": [round(float(v), 4) for v in o.center],
            "place": int(o.place),
            "approach_place": int(self.approach_place),
            "reason": self.reason,
        }


Goal = TypeVar("Goal", bound=GoalObject)


@dataclass
class GoalPlan(Generic[Goal]):
    """The plan to the first reachable candidate: its object, its approach place, and the
    better-scored candidates that were skipped (best first)."""

    plan: PathPlan
    goal_object: Goal
    goal_place: int
    skipped: list[SkippedGoal]


def plan_to_objects(
    graph: SceneGraph,
    cost_graph: CostGraph,
    start: int,
    candidates: Sequence[Goal],
    radius: float,
    what: str = "the destination",
) -> GoalPlan[Goal]:
    """Plan from `start` to the best-scored candidate object that can be reached.

    Candidates are tried by decreasing score; one is skipped when it has no approach place (see
    `approach_place`, `radius` metres) or A* finds no path to it under the terrain constraints.
    Raises NoPathError, listing why each candidate failed, only when none can be reached.
    """
    if not candidates:
        raise TerraError(f"no object matches {what}; lower --alpha or rephrase it")
    order = sorted(range(len(candidates)), key=lambda i: (-float(candidates[i].score), i))
    skipped: list[SkippedGoal] = []
    for i in order:
        obj = candidates[i]
        place, why = approach_place(graph, obj, cost_graph.allowed, radius)
        if place < 0:
            skipped.append(SkippedGoal(obj, -1, why))
            continue
        try:
            plan = plan_on(graph, cost_graph, start, place)
        except NoPathError as exc:
            skipped.append(SkippedGoal(obj, place, str(exc).removeprefix("no path: ")))
            continue
        return GoalPlan(plan, obj, place, skipped)
    reasons = "; ".join(
        f"{s.object.label!r} (score {s.object.score:.3f}) at place {s.object.place}: {s.reason}" for s in skipped[:3]
    )
    more = f"; and {len(skipped) - 3} more" if len(skipped) > 3 else ""
    raise NoPathError(f"no path to any of the {len(skipped)} objects for {what}: {reasons}{more}")
