"""Robot profiles: what a robot can drive over, applied to the places graph at planning time
(DESIGN.md decision 19; the graph is the same for every robot).

A profile reads the ground geometry of each place edge (terra.graph.ground: the largest step it
crosses, metres; its steepest rise and fall in the direction of travel, degrees):

- an edge is removed, in one direction, when its step exceeds `max_step` or, going that way, its
  rise exceeds `max_slope_up` or its fall exceeds `max_slope_down`;
- an edge is removed, both ways, when the ground across it is steeper than `max_cross_slope`
  (a contour along a hillside climbs little and tips the robot sideways; by default the steeper of
  `max_slope_up` and `max_slope_down`: ground no steeper than that in any direction is safe to
  cross). A graph whose bundle does not record it is read without this rule;
- an edge is removed when it crosses more than `max_unobserved` metres of ground the map never
  observed in one stretch: there only the heights at the stretch's two ends are known (a curb up
  and another down cancel out; a bridge over 27 m of unseen ground on the simulated campus crossed
  a 15 cm curb). A graph whose bundle does not record the stretch (written before it was) is read
  without this rule;
- a kept edge costs more the steeper it is: its cost (terra.tasks.planning) is multiplied by

      1 + slope_cost x max(rise / max_slope_up, fall / max_slope_down)

  so an edge at the profile's limit costs (1 + slope_cost) times a level one (a ratio is 0 for a
  level edge, and for a limit of 0 only a level edge is legal);
- places whose room (metres from the nearest obstacle, terra.graph.room) is below
  min_width / 2 are removed (their clearance, half the width of their terrain around them, where
  the graph does not record the room);
- `terrain_costs` and `forbidden_terrain` act as terrain penalties and forbidden terrains under
  the request's own preferences (`--prefer`, `--penalty`, `--forbid` win); terrains a map does not
  have are ignored, so one profile serves every map.

Every factor is >= 1, so A*'s straight-line heuristic stays admissible. The built-in profiles:
`wheelchair` (5 cm step, 8 degrees: a powered wheelchair on ramps steeper than the 1:12 of
building codes, 4.8 degrees), `wheeled` (10 cm, 15 degrees) and `legged` (20 cm, 35 degrees:
stairs are a slope of about 30 to 35 degrees); each accepts at most MAX_UNOBSERVED (5 m) of
unobserved ground in one stretch, as does a profile file that does not say, and each takes side
slopes as steep as its climbs.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import numpy as np
from pydantic import Field, ValidationError

from terra.errors import TerraError
from terra.schemas import NonEmptyStr, Strict, validation_message

Degrees = Annotated[float, Field(ge=0.0, le=90.0)]
MAX_UNOBSERVED = 5.0  # metres (module docstring)


class RobotProfile(Strict):
    """What one robot can drive over (module docstring). Lengths in metres, slopes in degrees."""

    name: NonEmptyStr = "custom"
    max_step: float = Field(ge=0.0, le=2.0, description="metres: the highest step (curb) the robot can climb")
    max_slope_up: Degrees = Field(description="degrees: the steepest climb")
    max_slope_down: Degrees = Field(description="degrees: the steepest descent")
    max_cross_slope: Degrees | None = Field(
        default=None, description="degrees: the steepest side slope (None: the steeper of max_slope_up, max_slope_down)"
    )
    min_width: float = Field(default=0.0, ge=0.0, le=20.0, description="metres: the narrowest passage")
    max_unobserved: float = Field(
        default=MAX_UNOBSERVED,
        ge=0.0,
        le=1e6,
        description="metres: the longest stretch of ground the map never observed that an edge may cross",
    )
    slope_cost: float = Field(
        default=1.0, ge=0.0, le=100.0, description="an edge at the slope limit costs (1 + this) x a level one"
    )
    terrain_costs: dict[NonEmptyStr, Annotated[float, Field(ge=0.0)]] = Field(
        default_factory=dict, description="terrain name -> penalty per metre (as --penalty)"
    )
    forbidden_terrain: list[NonEmptyStr] = Field(default_factory=list, description="terrains never to enter")

    def limits(self) -> str:
        """One phrase naming the profile's limits, for messages."""
        return (
            f"robot {self.name!r} (steps up to {self.max_step:g} m, climbs up to {self.max_slope_up:g} deg, descents "
            f"up to {self.max_slope_down:g} deg, side slopes up to {self.cross_limit:g} deg, passages from "
            f"{self.min_width:g} m, unobserved ground up to {self.max_unobserved:g} m)"
        )

    @property
    def cross_limit(self) -> float:
        """Degrees: the steepest slope across an edge the robot may drive along."""
        return max(self.max_slope_up, self.max_slope_down) if self.max_cross_slope is None else self.max_cross_slope

    def key(self) -> str:
        """A text that identifies the profile's values (for caches of cost graphs)."""
        return self.model_dump_json()

    def edge_rules(self, geometry: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """For place edges with ground geometry (E, 5) (step m, rise deg, fall deg, from edge[:, 0]
        to edge[:, 1], unobserved stretch m, cross slope deg; the last two NaN where not recorded):
        the cost factor (2E,) >= 1 and whether the edge is legal (2E,), first for every edge
        forwards, then backwards (module docstring)."""
        step, rise, fall, unobserved, cross = (np.asarray(geometry, dtype=np.float64)[:, k] for k in range(5))
        up, down = np.concatenate([rise, fall]), np.concatenate([fall, rise])
        steps = np.concatenate([step, step])
        # NaN, not recorded: no rule
        seen = np.tile(~(unobserved > self.max_unobserved) & ~(cross > self.cross_limit), 2)
        legal = (steps <= self.max_step) & (up <= self.max_slope_up) & (down <= self.max_slope_down) & seen
        ratio = np.maximum(_share(up, self.max_slope_up), _share(down, self.max_slope_down))
        return 1.0 + self.slope_cost * np.where(legal, ratio, 0.0), legal


def _share(slope: np.ndarray, limit: float) -> np.ndarray:
    """slope / limit, 0 where the slope is 0 (also for a limit of 0)."""
    return np.divide(slope, limit, out=np.zeros_like(slope), where=(slope > 0) & (limit > 0))


ROBOTS: dict[str, RobotProfile] = {
    "wheelchair": RobotProfile(
        name="wheelchair", max_step=0.05, max_slope_up=8.0, max_slope_down=8.0, min_width=0.9, slope_cost=2.0
    ),
    "wheeled": RobotProfile(
        name="wheeled", max_step=0.10, max_slope_up=15.0, max_slope_down=15.0, min_width=0.6, slope_cost=1.0
    ),
    "legged": RobotProfile(
        name="legged", max_step=0.20, max_slope_up=35.0, max_slope_down=35.0, min_width=0.5, slope_cost=0.5
    ),
}
ROBOT_NAMES = tuple(ROBOTS)
RobotSpec = str | RobotProfile  # a built-in name, or a profile


def robot_profile(spec: RobotSpec, source: str = "robot") -> RobotProfile:
    """The profile a request, config or task file names: a built-in name or a profile itself;
    TerraError naming `source` for an unknown name."""
    if isinstance(spec, RobotProfile):
        return spec
    profile = ROBOTS.get(spec.strip().lower())
    if profile is None:
        raise TerraError(f"{source}: unknown robot {spec!r}; expected one of {', '.join(ROBOT_NAMES)} or a profile")
    return profile


def load_robot(value: str) -> RobotSpec:
    """`--robot VALUE`: a built-in name as it is, else the profile in YAML file VALUE; TerraError
    (one line naming the file and field) for a missing file, unknown keys or impossible values."""
    from terra.fileio import read_yaml

    if value.strip().lower() in ROBOTS:
        return value.strip().lower()
    path = Path(value)
    if not path.is_file():
        raise TerraError(f"--robot {value!r}: expected {', '.join(ROBOT_NAMES)} or a profile file (none there)")
    raw = read_yaml(path, "robot profile")
    if not isinstance(raw, dict):
        raise TerraError(f"{path}: expected a mapping with keys such as max_step, max_slope_up, max_slope_down")
    try:
        return RobotProfile.model_validate({"name": path.stem, **raw})
    except ValidationError as exc:
        raise TerraError(validation_message(str(path), exc)) from None
