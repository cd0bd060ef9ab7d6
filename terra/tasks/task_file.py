"""Task files: YAML task lists shaped like the reference implementation's, so its users can bring
theirs to `terra find|monitor|plan --tasks FILE`.

Keys (all optional; the commands' own options win over the file):
- `object_tasks` (or `tasks`): [{task: "get bike from the bicycle rack"}, ...] for `terra find`.
- `region_tasks`: [{task: "...", place_nodes: [...]}] for `terra monitor` (place_nodes, the
  reference's hand labels, are kept for evaluation).
- `alpha`, `k`, `prediction_method`: ms_avg | ms_max | 3dsg | 3dsg_avg | 3dsg_max (objects),
  max | thresh | mix | aib (regions).
- `terrain_preferences`: {preferred: [...], forbidden: [...], penalties: {terrain: w}}, terrains
  by index into the terrain classes (as the reference writes them) or by name.
- `queries`: {start: place id | text query | null, destination: text query | place id}.
- `robot`: for `terra plan`, wheelchair | wheeled | legged or a profile mapping (terra.tasks.robot).
- `terra`, `trim`, `case`, `bounds`: reference settings with no meaning here; accepted, ignored.
Items may also be plain strings. Anything else is refused with the file and field named.

One file may drive all three commands: each uses its own keys (`COMMAND_KEYS`) and
`prediction_method` where it names a method of its kind (an object method for find and plan, a
region method for monitor); `unused_keys` lists what a command leaves aside, for a note.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from pydantic import Field, ValidationError, field_validator

from terra.errors import TerraError
from terra.schemas import Strict, validation_message
from terra.tasks.robot import RobotProfile

OBJECT_METHODS = {
    "ms_avg": ("ms-avg", None),
    "ms_max": ("ms-max", None),
    "3dsg": ("3dsg", None),
    "3dsg_avg": ("3dsg", "avg"),
    "3dsg_max": ("3dsg", "max"),
    "ms-avg": ("ms-avg", None),
    "ms-max": ("ms-max", None),
}
REGION_METHODS = ("max", "thresh", "mix", "aib")
COMMAND_KEYS = {
    "find": {"object_tasks", "tasks", "alpha", "prediction_method"},
    "monitor": {"region_tasks", "alpha", "k", "prediction_method"},
    "plan": {"terrain_preferences", "queries", "alpha", "prediction_method", "robot"},
}


class TaskItem(Strict):
    task: str
    label: str | int | None = None
    place_nodes: list[int] | None = None


class TerrainPreferences(Strict):
    preferred: list[int | str] = Field(default_factory=list)
    forbidden: list[int | str] = Field(default_factory=list)
    penalties: dict[int | str, float] = Field(default_factory=dict)

    @field_validator("preferred", "forbidden", mode="before")
    @classmethod
    def _no_list(cls, value: Any) -> Any:
        return [] if value is None else value

    @field_validator("penalties", mode="before")
    @classmethod
    def _no_mapping(cls, value: Any) -> Any:
        return {} if value is None else value


class PlanQueries(Strict):
    start: int | str | None = None
    destination: int | str | None = None


class TaskFile(Strict):
    terra: str | None = None
    alpha: float | None = None
    k: int | None = Field(default=None, ge=1)
    prediction_method: str | None = None
    trim: float | None = None
    case: Any = None
    bounds: Any = None
    object_tasks: list[TaskItem] = Field(default_factory=list)
    tasks: list[TaskItem] = Field(default_factory=list)
    region_tasks: list[TaskItem] = Field(default_factory=list)
    terrain_preferences: TerrainPreferences = Field(default_factory=TerrainPreferences)
    queries: PlanQueries = Field(default_factory=PlanQueries)
    robot: str | RobotProfile | None = None  # terra plan: a built-in robot name or a profile

    @field_validator("object_tasks", "tasks", "region_tasks", mode="before")
    @classmethod
    def _items(cls, value: Any) -> Any:
        if value is None:
            return []
        if isinstance(value, list):
            return [{"task": v} if isinstance(v, str) else v for v in value]
        return value

    @field_validator("terrain_preferences", "queries", mode="before")
    @classmethod
    def _empty_section(cls, value: Any) -> Any:
        return {} if value is None else value

    def object_queries(self) -> list[str]:
        return [t.task for t in self.object_tasks + self.tasks]

    def region_queries(self) -> list[str]:
        return [t.task for t in self.region_tasks]

    def unused_keys(self, command: str) -> list[str]:
        """Keys set in the file that `command` (find, monitor or plan) does not use, in file order."""
        used = set(COMMAND_KEYS[command])
        method = self.prediction_method
        mine, theirs = (REGION_METHODS, OBJECT_METHODS) if command == "monitor" else (OBJECT_METHODS, REGION_METHODS)
        if method is not None and method not in mine and method in theirs:
            used.discard("prediction_method")  # a method of the other kind: the other command's
        return [k for k in type(self).model_fields if k in self.model_fields_set and k not in used]

    def object_method(self, source: str) -> tuple[str | None, str | None]:
        """(retrieval method, 3DSG point feature or None) from `prediction_method`; (None, None)
        when it names a region method (the file's monitor task)."""
        if self.prediction_method is None or self.prediction_method in REGION_METHODS:
            return None, None
        if self.prediction_method not in OBJECT_METHODS:
            raise TerraError(
                f"{source}: field 'prediction_method' is {self.prediction_method!r}; for objects expected one of: "
                "ms_avg, ms_max, 3dsg, 3dsg_avg, 3dsg_max"
            )
        return OBJECT_METHODS[self.prediction_method]

    def region_method(self, source: str) -> str | None:
        """The monitoring method from `prediction_method`; None when it names an object method."""
        if self.prediction_method is None or self.prediction_method in OBJECT_METHODS:
            return None
        if self.prediction_method not in REGION_METHODS:
            raise TerraError(
                f"{source}: field 'prediction_method' is {self.prediction_method!r}; for regions expected one of: "
                f"{', '.join(REGION_METHODS)}"
            )
        return self.prediction_method


def load_task_file(path: str | Path) -> TaskFile:
    """Parse and validate a task file; TerraError (one line, file and field named) when malformed."""
    from terra.fileio import read_yaml

    path = Path(path)
    raw = read_yaml(path, "task file")
    if raw is None:
        raw = {}
    if not isinstance(raw, dict):
        raise TerraError(
            f"{path}: expected a mapping with keys such as object_tasks, region_tasks, terrain_preferences, queries"
        )
    try:
        return TaskFile.model_validate(raw)
    except ValidationError as exc:
        raise TerraError(validation_message(str(path), exc)) from None
