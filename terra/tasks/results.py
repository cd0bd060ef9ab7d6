"""What the task queries return: typed results whose `to_json()` is the JSON of `terra find/monitor/
plan --json` and of the `terra serve` responses (one shape for both). Text rendering lives in
terra/cli/render.py; nothing parses the JSON back."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # a monitor query must not import retrieval (and with it SciPy) to build its result
    from terra.graph.scene_graph import SceneGraph
    from terra.tasks.monitoring import MonitorResult
    from terra.tasks.planning import PathPlan, SkippedGoal
    from terra.tasks.retrieval import FoundObject
    from terra.tasks.robot import RobotProfile


@dataclass
class FindResult:
    """Objects for every query, best first per query; `saved` when they went into the graph."""

    bundle: Path
    method: str
    alpha: float
    queries: list[str]
    objects: list[FoundObject]
    saved: bool = False

    def to_json(self) -> dict[str, Any]:
        return {
            "bundle": str(self.bundle),
            "method": self.method,
            "alpha": self.alpha,
            "queries": list(self.queries),
            "objects": [dict(id=i, **o.to_json()) for i, o in enumerate(self.objects)],
            "saved": bool(self.saved),
        }


@dataclass
class MonitorResults:
    """One MonitorResult per query, with the parameters used and the graph they index."""

    bundle: Path
    method: str
    k: int
    alpha: float
    results: list[MonitorResult]
    graph: SceneGraph = field(repr=False)

    def to_json(self) -> dict[str, Any]:
        return {
            "bundle": str(self.bundle),
            "method": self.method,
            "k": self.k,
            "alpha": self.alpha,
            "results": [r.to_json(self.graph) for r in self.results],
        }


@dataclass
class PlanEnd:
    """A plan's start or goal: the place, how it was chosen, and the object when a query chose it.
    For a goal query: how many objects were candidates, and the better-scored ones skipped (why)."""

    place: int
    how: str = ""
    query: str | None = None
    object: FoundObject | None = None
    candidates: int = 0
    skipped: list[SkippedGoal] = field(default_factory=list)


def _object_json(end: PlanEnd) -> dict[str, Any] | None:
    """The JSON of the object that chose a plan's start or goal, None when a place or xy did."""
    return end.object.to_json() if end.object is not None else None


@dataclass
class PlanResult:
    """A planned path with its start, goal, the terrain preferences it honoured and the robot
    profile whose limits it kept (None: none)."""

    bundle: Path
    plan: PathPlan
    start: PlanEnd
    goal: PlanEnd
    penalty: dict[str, float]
    forbidden: list[str]
    robot: RobotProfile | None = None

    def to_json(self) -> dict[str, Any]:
        return {
            "bundle": str(self.bundle),
            **self.plan.to_json(),
            "start": {"place": self.start.place, "how": self.start.how, "object": _object_json(self.start)},
            "goal": {
                "place": self.goal.place,
                "query": self.goal.query,
                "object": _object_json(self.goal),
                "candidates": self.goal.candidates,
                "skipped": [s.to_json() for s in self.goal.skipped],
            },
            "preferences": {"penalty": dict(self.penalty), "forbidden": list(self.forbidden)},
            # The side slope limit it applies, where the profile leaves it to its climbs and descents.
            "robot": (
                self.robot.model_dump(mode="json") | {"max_cross_slope": self.robot.cross_limit}
                if self.robot is not None
                else None
            ),
        }
