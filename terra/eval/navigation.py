"""Navigation: the paper's "Get bike from the bicycle rack" experiment, measured.

Start: the place nearest (2-D) the first camera pose, where the robot began. Goal: the place of
the best object retrieved for the task (Terra-3DSG, the paper's choice for navigation). Two plans,
shortest and with the preferred terrains; each reports its length and the metres of it on each
ground-truth terrain (terra.eval.metrics.navigation).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from terra.datasets.ground_truth import TerrainRaster
from terra.errors import TerraError
from terra.eval.metrics.navigation import path_length, path_terrain_lengths
from terra.graph.scene_graph import SceneGraph
from terra.mapping.semantic_map import MetricSemanticMap


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


def plan_with(graph: SceneGraph, start: int, goal: int, name: str, raster: TerrainRaster, prefer: list[str] = (),
              step: float = 0.1, default_penalty: float = 1.0) -> PlanResult:
    """Plan start -> goal (preferring `prefer` terrains) and measure it against the ground truth."""
    from terra.tasks.planning import plan_path

    plan = plan_path(graph, start, goal, prefer=list(prefer), default_penalty=default_penalty)
    return PlanResult(name, np.asarray(plan.places), np.asarray(plan.waypoints), float(plan.cost),
                      dict(plan.length_by_terrain), path_terrain_lengths(plan.waypoints, raster, step))
