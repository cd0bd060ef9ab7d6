"""What a task query asks: the typed requests behind `terra find/monitor/plan` and `terra serve`.

The command line builds them from its options (and the reference's task files); the HTTP service
reads them from JSON bodies, whose keys are these field names (`from` for the start query). Unknown
keys are errors. Values the embedding space decides (alpha, k, method) default to the tasks
configuration when left out.
"""

from __future__ import annotations

from typing import Literal

from pydantic import ConfigDict, Field

from terra.schemas import Strict
from terra.tasks.config import MonitorMethod, RetrievalMethod
from terra.tasks.robot import RobotProfile

PointFeature = Literal["avg", "max"]


class TaskRequest(Strict):
    """Base of the requests: unknown keys are errors, instances are immutable."""

    model_config = ConfigDict(frozen=True, populate_by_name=True)


class FindRequest(TaskRequest):
    """Objects for text queries (Terra-MS or Terra-3DSG)."""

    queries: list[str] = Field(
        default_factory=list, description='Text queries, e.g. "find the dumpster"; one embedding batch.'
    )
    method: RetrievalMethod | None = Field(
        default=None, description="ms-avg, ms-max or 3dsg; default tasks.retrieval.method."
    )
    alpha: float | None = Field(
        default=None, ge=-1.0, le=1.0, description="Cosine threshold; default per embedder (tasks.retrieval.alpha)."
    )
    point_feature: PointFeature | None = Field(
        default=None, description="3dsg: point feature searched near the chosen places (avg or max)."
    )
    save: bool = Field(
        default=False, description="Store the objects in the bundle's scene graph (same-label objects are replaced)."
    )


class MonitorRequest(TaskRequest):
    """Regions and places to watch for monitoring tasks."""

    queries: list[str] = Field(default_factory=list, description='Monitoring task texts, e.g. "large parking lot".')
    method: MonitorMethod | None = Field(
        default=None, description="mix (paper), max, thresh or aib; default tasks.monitoring.method."
    )
    k: int | None = Field(
        default=None, ge=1, description="Number of top regions for mix and max; default tasks.monitoring.k."
    )
    alpha: float | None = Field(
        default=None, ge=-1.0, le=1.0, description="Cosine threshold; default per embedder (tasks.monitoring.alpha)."
    )


class PlanRequest(TaskRequest):
    """A terrain-aware path from a start to the place of an object (or a place id)."""

    to: str | None = Field(default=None, description='Destination task, e.g. "get bike from the bicycle rack".')
    to_node: int | None = Field(default=None, ge=0, description="Destination place id instead of a query.")
    from_query: str | None = Field(default=None, alias="from", description="Start at the object this query names.")
    from_node: int | None = Field(default=None, ge=0, description="Start place id.")
    from_xy: tuple[float, float] | None = Field(
        default=None, description="Start at the allowed place nearest (x, y), metres, map frame."
    )
    prefer: list[str] = Field(
        default_factory=list, description="Preferred terrains; others get tasks.planning.default_penalty."
    )
    penalty: dict[str, float] = Field(
        default_factory=dict, description="Terrain name (or index) -> penalty >= 0 per metre."
    )
    forbid: list[str] = Field(default_factory=list, description="Terrains never to enter.")
    robot: str | RobotProfile | None = Field(
        default=None,
        description="Robot profile: wheelchair, wheeled, legged, or a profile (max_step, max_slope_up, ...); "
        "default tasks.planning.robot.",
    )
    method: RetrievalMethod | None = Field(
        default=None, description="Retrieval method for the queries; default tasks.planning.find_method."
    )
    alpha: float | None = Field(default=None, ge=-1.0, le=1.0, description="Cosine threshold for the queries.")
    point_feature: PointFeature | None = Field(default=None, description="3dsg point feature (avg or max).")
