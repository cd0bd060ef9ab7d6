"""Command-line options of `terra find/monitor/plan` turned into typed task requests: flag checks
with the flags' names in the messages, TERRAIN=WEIGHT parsing, and the reference's YAML task files
(their values fill what the flags leave unset). No commands live here."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from terra.errors import TerraError

if TYPE_CHECKING:  # every cli module is imported for `terra --help`: pydantic models load on use
    from pydantic import BaseModel

    from terra.loaded import LoadedBundle
    from terra.tasks.config import TasksConfig
    from terra.tasks.requests import FindRequest, MonitorRequest, PlanRequest
    from terra.tasks.task_file import TaskFile

R = TypeVar("R", bound="BaseModel")


def load_tasks_config(path: Path | None) -> TasksConfig:
    from terra.config import TerraConfig

    return TerraConfig.read(path).tasks


def open_bundle(path: Path, config: TasksConfig) -> LoadedBundle:
    from terra.loaded import LoadedBundle

    return LoadedBundle(path, embedder_name=config.embedder)


def check_choice(option: str, value: str | None, choices: Sequence[str]) -> None:
    if value is not None and value not in choices:
        raise TerraError(f"{option} {value!r}: expected one of {', '.join(choices)}")


def check_alpha(alpha: float | None) -> float | None:
    if alpha is not None and not -1.0 <= alpha <= 1.0:
        raise TerraError(f"--alpha is a cosine similarity threshold in [-1, 1], got {alpha}")
    return alpha


def parse_penalties(items: Sequence[str]) -> dict[str, float]:
    """["grass=5", "dirt=2.5"] -> {"grass": 5.0, "dirt": 2.5}; TerraError on a malformed item."""
    out: dict[str, float] = {}
    for item in items:
        name, sep, value = item.partition("=")
        try:
            if not sep or not name.strip():
                raise ValueError
            out[name.strip()] = float(value)
        except ValueError:
            raise TerraError(f"--penalty expects TERRAIN=WEIGHT (e.g. grass=5), got {item!r}") from None
    return out


def build(model: type[R], source: str, values: dict[str, Any]) -> R:
    """`model` from `values`; TerraError (one line naming the field) when they do not fit."""
    from pydantic import ValidationError

    from terra.schemas import validation_message

    try:
        return model.model_validate(values)
    except ValidationError as exc:
        raise TerraError(validation_message(source, exc)) from None


def _task_file(path: Path | None, command: str) -> TaskFile:
    """The task file (empty without one); keys `command` does not use are noted on stderr when the
    command succeeds, so one file can drive find, monitor and plan."""
    from terra.tasks.task_file import TaskFile, load_task_file

    if path is None:
        return TaskFile()
    task_file = load_task_file(path)
    unused = task_file.unused_keys(command)
    if unused:
        from terra.cli import note

        note(f"{path}: {', '.join(unused)} not used by terra {command} (ignored)")
    return task_file


def find_request(
    queries: Sequence[str], method: str | None, alpha: float | None, save: bool, tasks: Path | None
) -> FindRequest:
    """Command-line queries first, then the task file's; flags win over the file's values."""
    from terra.tasks.config import RETRIEVAL_METHODS
    from terra.tasks.requests import FindRequest

    check_choice("--method", method, RETRIEVAL_METHODS)
    task_file = _task_file(tasks, "find")
    file_method, feature = task_file.object_method(str(tasks))
    alpha = check_alpha(alpha if alpha is not None else task_file.alpha)
    return build(
        FindRequest,
        "command line",
        {
            "queries": list(queries) + task_file.object_queries(),
            "method": method or file_method,
            "alpha": alpha,
            "point_feature": feature,
            "save": save,
        },
    )


def monitor_request(
    queries: Sequence[str], method: str | None, k: int | None, alpha: float | None, tasks: Path | None
) -> MonitorRequest:
    from terra.tasks.config import MONITOR_METHODS
    from terra.tasks.requests import MonitorRequest

    check_choice("--method", method, MONITOR_METHODS)
    task_file = _task_file(tasks, "monitor")
    alpha = check_alpha(alpha if alpha is not None else task_file.alpha)
    return build(
        MonitorRequest,
        "command line",
        {
            "queries": list(queries) + task_file.region_queries(),
            "method": method or task_file.region_method(str(tasks)),
            "k": k if k is not None else task_file.k,
            "alpha": alpha,
        },
    )


def plan_request(
    to: str | None = None,
    to_node: int | None = None,
    from_query: str | None = None,
    from_node: int | None = None,
    from_xy: tuple[float, float] | None = None,
    prefer: Sequence[str] = (),
    penalty: Sequence[str] = (),
    forbid: Sequence[str] = (),
    method: str | None = None,
    alpha: float | None = None,
    tasks: Path | None = None,
    robot: str | None = None,
) -> PlanRequest:
    """Flags first; the task file's terrain preferences are merged under them and its start,
    destination and robot fill what the flags leave unset. `robot`: a built-in name or a profile
    file (terra.tasks.robot.load_robot)."""
    from terra.tasks.config import RETRIEVAL_METHODS
    from terra.tasks.requests import PlanRequest
    from terra.tasks.robot import load_robot

    check_choice("--method", method, RETRIEVAL_METHODS)
    task_file = _task_file(tasks, "plan")
    prefs = task_file.terrain_preferences
    dest, start = task_file.queries.destination, task_file.queries.start
    if to is None and to_node is None:
        to, to_node = (None, dest) if isinstance(dest, int) else (dest, None)
    if from_query is None and from_node is None and from_xy is None:
        from_query, from_node = (None, start) if isinstance(start, int) else (start, None)
    file_method, feature = task_file.object_method(str(tasks))
    penalties = {str(k): float(v) for k, v in prefs.penalties.items()}
    penalties.update(parse_penalties(penalty))
    return build(
        PlanRequest,
        "command line",
        {
            "to": to,
            "to_node": to_node,
            "from": from_query,
            "from_node": from_node,
            "from_xy": from_xy,
            "prefer": [str(t) for t in prefs.preferred] + list(prefer),
            "penalty": penalties,
            "forbid": [str(t) for t in prefs.forbidden] + list(forbid),
            "method": method or file_method,
            "alpha": check_alpha(alpha if alpha is not None else task_file.alpha),
            "point_feature": feature,
            "robot": load_robot(robot) if robot is not None else task_file.robot,
        },
    )
