"""Navigation: the paper's "Get bike from the bicycle rack" experiment, measured.

Start: the place nearest (2-D) the first camera pose, where the robot began. Goal: the place of
the best object retrieved for the task (Terra-3DSG, the paper's choice for navigation). Two plans,
shortest and with the preferred terrains; each reports its length and the metres of it on each
ground-truth terrain (terra.eval.metrics.navigation).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree  # pyright: ignore[reportAttributeAccessIssue]  (compiled, no stub)

from terra.datasets.ground_truth import TerrainRaster
from terra.errors import TerraError
from terra.eval.metrics.navigation import path_length, path_terrain_lengths
from terra.graph.scene_graph import SceneGraph
from terra.mapping.semantic_map import MetricSemanticMap
from terra.tasks.config import DEFAULT_PENALTY


def start_place(msm: MetricSemanticMap, graph: SceneGraph) -> int:
    """The place nearest (2-D) the first camera pose, or to the first map point without images."""
    if len(graph.places) == 0:
        raise TerraError("the scene graph has no places to plan on")
    anchor = msm.images.position[0] if len(msm.images) else msm.points[0]
    return int(cKDTree(graph.places.position[:, :2]).query(np.asarray(anchor, float)[:2])[1])


@dataclass
class PlanResult:
    """A plan's places and its measured lengths (metres)."""

    name: str
    places: np.ndarray
    waypoints: np.ndarray
    cost: float
    planner_terrain_m: dict[str, float]
    gt_terrain_m: dict[str, float]

    @property
    def length_m(self) -> float:
        return path_length(self.waypoints)

    def to_json(self) -> dict:
        return {
            "places": int(len(self.places)),
            "place_indices": [int(p) for p in self.places],
            "length_m": self.length_m,
            "cost": self.cost,
            "planner_terrain_m": dict(sorted(self.planner_terrain_m.items())),
            "gt_terrain_m": dict(sorted(self.gt_terrain_m.items())),
        }


def plan_with(
    graph: SceneGraph,
    start: int,
    goal: int,
    name: str,
    raster: TerrainRaster,
    prefer: Sequence[str] = (),
    step: float = 0.1,
    default_penalty: float = DEFAULT_PENALTY,
) -> PlanResult:
    """Plan start -> goal (preferring `prefer` terrains) and measure it against the ground truth."""
    from terra.tasks.planning import plan_path

    plan = plan_path(graph, start, goal, prefer=list(prefer), default_penalty=default_penalty)
    return PlanResult(
        name,
        np.asarray(plan.places),
        np.asarray(plan.waypoints),
        float(plan.cost),
        dict(plan.length_by_terrain),
        path_terrain_lengths(plan.waypoints, raster, step),
    )


# ---------------------------------------------------------------- preferring a terrain where it runs


def robot_path(msm: MetricSemanticMap) -> np.ndarray:
    """(n, 2) xy (metres, map frame) of the camera poses in capture order: the robot's path."""
    if len(msm.images) == 0:
        return np.zeros((0, 2))
    return np.asarray(msm.images.T_map_cam, dtype=np.float64)[:, :2, 3]


def terrain_route_pairs(
    graph: SceneGraph,
    raster: TerrainRaster,
    terrain: str,
    seen: np.ndarray | None = None,
    max_pairs: int = 200,
    seed: int = 0,
) -> np.ndarray:
    """(k, 2) place pairs (i < j) between which a route on `terrain` exists in the world: both
    places are of that terrain in the graph and on one 8-connected component of its cells in the
    ground-truth raster (over the `seen` cells only, when given). All pairs, or `max_pairs` of
    them drawn with a fixed seed."""
    from terra.eval.metrics.places import eight_components

    if terrain not in graph.terrain_classes or terrain not in raster.legend.values():
        return np.zeros((0, 2), dtype=np.int64)
    cid = next(k for k, v in raster.legend.items() if v == terrain)
    cells = raster.classes == cid
    labels = eight_components(cells if seen is None else cells & seen)
    mine = np.flatnonzero(graph.places.terrain == graph.terrain_classes.index(terrain))
    rows, cols, inside = raster.cell_of(graph.places.position[mine, :2])
    component = np.where(inside, labels[rows, cols], 0)
    i, j = np.triu_indices(len(mine), 1)
    same = (component[i] == component[j]) & (component[i] > 0)
    pairs = np.column_stack([mine[i[same]], mine[j[same]]])
    if len(pairs) > max_pairs:
        pairs = pairs[np.sort(np.random.default_rng(seed).choice(len(pairs), max_pairs, replace=False))]
    return pairs.astype(np.int64)


@dataclass
class PreferenceRoutes:
    """Shortest and preferred plans between place pairs, with the ground-truth metres of each on
    the preferred terrain and in total."""

    pairs: np.ndarray
    shortest: list[PlanResult]
    preferred: list[PlanResult]
    terrain: str

    def share(self, plans: list[PlanResult]) -> np.ndarray:
        """(k,) share of each plan's length on the preferred terrain (1 for zero-length plans)."""
        return np.array([p.gt_terrain_m.get(self.terrain, 0.0) / p.length_m if p.length_m > 0 else 1.0 for p in plans])

    def to_json(self, min_share: float) -> dict:
        share = self.share(self.preferred)
        return {
            "terrain": self.terrain,
            "pairs": int(len(self.pairs)),
            "min_share": min_share,
            "preferred_mean_share": float(share.mean()) if len(share) else None,
            "preferred_lowest_share": float(share.min()) if len(share) else None,
            "shortest_mean_share": float(self.share(self.shortest).mean()) if len(share) else None,
            "pairs_meeting": int((share >= min_share).sum()),
            "fraction_meeting": float((share >= min_share).mean()) if len(share) else None,
        }


def preference_routes(
    graph: SceneGraph,
    raster: TerrainRaster,
    pairs: np.ndarray,
    terrain: str,
    step: float = 0.1,
    default_penalty: float = DEFAULT_PENALTY,
) -> PreferenceRoutes:
    """Both plans (shortest; preferring `terrain`) for every pair, measured on the raster."""
    shortest, preferred = [], []
    for a, b in np.asarray(pairs, dtype=np.int64).reshape(-1, 2).tolist():
        shortest.append(plan_with(graph, a, b, "shortest", raster, (), step, default_penalty))
        preferred.append(plan_with(graph, a, b, f"prefer {terrain}", raster, (terrain,), step, default_penalty))
    return PreferenceRoutes(np.asarray(pairs, dtype=np.int64).reshape(-1, 2), shortest, preferred, terrain)


def preference_case(routes: PreferenceRoutes, min_share: float = 0.8) -> int | None:
    """Index of the pair that shows the preference best: among pairs whose preferred plan keeps at
    least `min_share` of its length on the terrain and whose shortest plan leaves it, the one whose
    preference moves the most metres onto it (first on ties); None when no pair qualifies."""
    if len(routes.pairs) == 0:
        return None
    on_short = np.array([p.gt_terrain_m.get(routes.terrain, 0.0) for p in routes.shortest])
    off_short = np.array([p.length_m for p in routes.shortest]) - on_short
    off_pref = np.array([p.length_m - p.gt_terrain_m.get(routes.terrain, 0.0) for p in routes.preferred])
    gain = off_short - off_pref
    ok = (routes.share(routes.preferred) >= min_share) & (off_short > 0.5) & (gain > 0)
    if not ok.any():
        return None
    return int(np.flatnonzero(ok & (gain >= gain[ok].max() - 1e-6))[0])  # millimetre ties: the first pair


# ---------------------------------------------------------------- choosing the planner's penalty


@dataclass
class PenaltyPoint:
    """The preferred plans of one penalty over a set of pairs: share of pairs keeping at least
    `min_share` of their length on the terrain, and the detour against the shortest plans
    (length ratio preferred / shortest; extra metres)."""

    penalty: float
    pairs: int
    meeting: int
    mean_share: float
    mean_detour: float
    max_detour: float
    max_extra_m: float

    @property
    def fraction_meeting(self) -> float:
        return self.meeting / self.pairs if self.pairs else 1.0

    def to_json(self) -> dict:
        return {
            "penalty": self.penalty,
            "pairs": self.pairs,
            "meeting": self.meeting,
            "fraction_meeting": self.fraction_meeting,
            "mean_share": self.mean_share,
            "mean_detour": self.mean_detour,
            "max_detour": self.max_detour,
            "max_extra_m": self.max_extra_m,
        }


def penalty_sweep(
    graph: SceneGraph,
    raster: TerrainRaster,
    pairs: np.ndarray,
    terrain: str,
    penalties: list[float],
    min_share: float = 0.8,
    step: float = 0.1,
) -> list[PenaltyPoint]:
    """For each planner `default_penalty` in `penalties`, the plans preferring `terrain` between
    the `pairs` measured on the ground-truth raster (a validation scene's, never a test scene's)."""
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    shortest = np.array([plan_with(graph, a, b, "shortest", raster, (), step).length_m for a, b in pairs.tolist()])
    out = []
    for penalty in penalties:
        plans = [
            plan_with(graph, a, b, "preferred", raster, (terrain,), step, float(penalty)) for a, b in pairs.tolist()
        ]
        length = np.array([p.length_m for p in plans])
        share = np.array([p.gt_terrain_m.get(terrain, 0.0) / p.length_m if p.length_m > 0 else 1.0 for p in plans])
        detour = np.where(shortest > 0, length / np.maximum(shortest, 1e-12), 1.0)
        out.append(
            PenaltyPoint(
                float(penalty),
                len(pairs),
                int((share >= min_share).sum()),
                float(share.mean()) if len(share) else 1.0,
                float(detour.mean()) if len(detour) else 1.0,
                float(detour.max()) if len(detour) else 1.0,
                float((length - shortest).max()) if len(length) else 0.0,
            )
        )
    return out


def choose_penalty(points: list[PenaltyPoint]) -> float:
    """The smallest penalty whose plans keep the most pairs at or above the share: a larger one
    only lengthens detours without moving another pair onto the terrain. Every penalty bounds its
    own detour (a plan costs at most (1 + penalty) x the shortest plan's length), so the smallest
    sufficient one is also the one with the shortest detours."""
    if not points:
        raise TerraError("no penalties to choose from")
    best = max(p.fraction_meeting for p in points)
    return min(p.penalty for p in points if p.fraction_meeting >= best - 1e-12)
