"""Configuration: one YAML file per command, read once into a `TerraConfig` that hands each stage
its pydantic section.

A config file holds any of the top-level keys `sim`, `odometry`, `mapping`, `build`, `tasks`,
`eval`, and `dataset`; missing keys take defaults. `terra config dump STAGE` prints a stage's
defaults as YAML. The `dataset` section holds the options of the source's loader (topics,
frames, tolerances; see the loader's config section), so it is validated by the loader that
opens the source, not here (`TerraConfig.dataset`).

A command reads its file once (`TerraConfig.read`, which refuses an unreadable file or an unknown
top-level key) and asks it for the sections it runs (`config.mapping`, `config.tasks`, ...). Each
section is validated, and its class imported, on first use: the query commands read the `tasks`
section and must not import the simulator's (numba) or mapping's modules to do so, and a bad
section a command does not use does not stop it.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import yaml
from pydantic import BaseModel, ValidationError

from terra.errors import TerraError
from terra.schemas import validation_message

if TYPE_CHECKING:
    from terra.eval.config import EvalConfig
    from terra.graph.config import BuildConfig
    from terra.mapping.config import MappingConfig
    from terra.odometry.config import OdometryConfig
    from terra.sim.config import SimConfig
    from terra.tasks.config import TasksConfig


# Stage -> "module:Class", imported only when that stage is asked for (see the module docstring).
_SECTIONS = {
    "sim": "terra.sim.config:SimConfig",
    "odometry": "terra.odometry.config:OdometryConfig",
    "mapping": "terra.mapping.config:MappingConfig",
    "build": "terra.graph.config:BuildConfig",
    "tasks": "terra.tasks.config:TasksConfig",
    "eval": "terra.eval.config:EvalConfig",
}
DATASET_KEY = "dataset"  # loader options, validated by the loader (terra.datasets.registry.open_dataset)


def _section_class(stage: str) -> type[BaseModel]:
    import importlib

    module, _, name = _SECTIONS[stage].partition(":")
    return getattr(importlib.import_module(module), name)


def stage_names() -> list[str]:
    return list(_SECTIONS)


class TerraConfig:
    """The configuration of one command: the top-level mapping of its YAML file (defaults without
    one), with the command's overrides (e.g. `--noise`) merged in per stage. Sections are
    validated on first use and kept."""

    def __init__(self, raw: dict[str, Any] | None = None, source: str = "defaults"):
        self.raw: dict[str, Any] = dict(raw or {})
        self.source = source  # the file's path, or "defaults", for messages
        self._sections: dict[str, BaseModel] = {}

    @classmethod
    def read(cls, path: str | Path | None, overrides: dict[str, dict | None] | None = None) -> TerraConfig:
        """The config file `path` (defaults when None), read once; `overrides`: per stage, values
        that take the place of the file's (e.g. {"mapping": {"perception": {"noise": "realistic"}}})."""
        config = cls(_read_config(Path(path)), str(path)) if path is not None else cls()
        return config.with_overrides(overrides) if overrides else config

    def with_overrides(self, overrides: dict[str, dict | None]) -> TerraConfig:
        """This configuration with `overrides` (per stage) merged in; the file is not read again."""
        for stage in overrides:
            _check_stage(stage)
        raw = dict(self.raw)
        for stage, values in overrides.items():
            raw[stage] = _deep_merge(self._stage_data(stage), values or {})
        return TerraConfig(raw, self.source)

    def sets(self, *keys: str) -> bool:
        """Whether the file (or an override) sets the option at `keys`, e.g. ("mapping", "perception", "noise")."""
        node: Any = self.raw
        for key in keys:
            if not isinstance(node, dict) or key not in node:
                return False
            node = node[key]
        return True

    def section(self, stage: str) -> BaseModel:
        """The validated section `stage` (TerraError naming the file, the stage and the first bad field)."""
        _check_stage(stage)
        if stage not in self._sections:
            try:
                self._sections[stage] = _section_class(stage).model_validate(self._stage_data(stage))
            except ValidationError as exc:
                raise TerraError(validation_message(f"{self.source} [{stage}]", exc)) from None
        return self._sections[stage]

    def _stage_data(self, stage: str) -> dict[str, Any]:
        data = self.raw.get(stage)
        if data is None:
            return {}
        if not isinstance(data, dict):
            raise TerraError(
                f"{self.source}: field '{stage}' must be a mapping of the {stage} section's options "
                f"(see `terra config dump {stage}`), got {type(data).__name__}"
            )
        return data

    @property
    def sim(self) -> SimConfig:
        return cast("SimConfig", self.section("sim"))

    @property
    def odometry(self) -> OdometryConfig:
        return cast("OdometryConfig", self.section("odometry"))

    @property
    def mapping(self) -> MappingConfig:
        return cast("MappingConfig", self.section("mapping"))

    @property
    def build(self) -> BuildConfig:
        return cast("BuildConfig", self.section("build"))

    @property
    def tasks(self) -> TasksConfig:
        return cast("TasksConfig", self.section("tasks"))

    @property
    def eval(self) -> EvalConfig:
        return cast("EvalConfig", self.section("eval"))

    @property
    def dataset(self) -> dict[str, Any]:
        """The `dataset` section as a plain mapping ({} without one); the loader that opens the
        source validates it against its own options section."""
        options = self.raw.get(DATASET_KEY) or {}
        if not isinstance(options, dict):
            raise TerraError(f"{self.source}: field 'dataset' must be a mapping of the loader's options")
        return options


def _check_stage(stage: str) -> None:
    if stage not in _SECTIONS:
        raise TerraError(f"unknown config stage {stage!r}; expected one of: {', '.join(_SECTIONS)}")


def _read_config(path: Path) -> dict[str, Any]:
    """The top-level mapping of a config file; TerraError for unreadable YAML or an unknown key."""
    from terra.fileio import read_yaml

    keys = [*_SECTIONS, DATASET_KEY]
    raw = read_yaml(path, "config file") or {}
    if not isinstance(raw, dict):
        raise TerraError(f"{path}: expected a mapping with keys among {', '.join(keys)}")
    unknown = [key for key in raw if key not in keys]
    if unknown:
        raise TerraError(
            f"{path}: unknown top-level key {str(unknown[0])[:60]!r}; expected keys among {', '.join(keys)}"
        )
    return raw


def load_section(path: str | Path | None, stage: str, overrides: dict | None = None) -> BaseModel:
    """The config section `stage` of the file at `path` (defaults when None), with overrides: one
    section read on its own. A command reads its file once with `TerraConfig.read` instead."""
    _check_stage(stage)
    return TerraConfig.read(path, {stage: overrides} if overrides else None).section(stage)


def load_dataset_options(path: str | Path | None) -> dict:
    """The `dataset` section of the file at `path` ({} without one): see `TerraConfig.dataset`."""
    return TerraConfig.read(path).dataset


def _deep_merge(base: dict, extra: dict) -> dict:
    out = dict(base)
    for key, value in extra.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _deep_merge(out[key], value)
        else:
            out[key] = value
    return out


def dump_section(stage: str) -> str:
    """Defaults of one stage as YAML text, under its top-level key."""
    section = TerraConfig().section(stage)
    return yaml.safe_dump({stage: section.model_dump(mode="json")}, sort_keys=False)
