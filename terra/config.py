"""Configuration: one pydantic section per pipeline stage, loaded from YAML.

A config file holds any of the top-level keys `sim`, `odometry`, `mapping`, `build`, `tasks`,
`eval`, and `dataset`; missing keys take defaults. `terra config dump STAGE` prints a stage's
defaults as YAML. The `dataset` section holds the options of the source's loader (topics,
frames, tolerances; see the loader's config section), so it is validated by the loader that
opens the source, not here (`load_dataset_options`).
"""

from __future__ import annotations

from pathlib import Path
from typing import TypeVar

import yaml
from pydantic import BaseModel, ConfigDict, ValidationError

from terra.errors import TerraError


class Section(BaseModel):
    """Base of every config section: unknown keys are errors, values are validated on assignment."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True, allow_inf_nan=False)


S = TypeVar("S", bound=BaseModel)


# Stage -> "module:Class", imported only when that stage is loaded: the query commands read the
# `tasks` section and must not import the simulator's (numba) or mapping's modules to do so.
_SECTIONS = {
    "sim": "terra.sim.config:SimConfig",
    "odometry": "terra.odometry.config:OdometryConfig",
    "mapping": "terra.mapping.config:MappingConfig",
    "build": "terra.graph.config:BuildConfig",
    "tasks": "terra.tasks.config:TasksConfig",
    "eval": "terra.eval.config:EvalConfig",
}


def _section(stage: str) -> type[BaseModel]:
    import importlib

    module, _, name = _SECTIONS[stage].partition(":")
    return getattr(importlib.import_module(module), name)


DATASET_KEY = "dataset"  # loader options, validated by the loader (terra.datasets.registry.open_dataset)


def stage_names() -> list[str]:
    return list(_SECTIONS)


def validation_message(source: str, exc: ValidationError) -> str:
    """One line naming the first bad field and what was expected."""
    err = exc.errors()[0]
    where = ".".join(str(p) for p in err["loc"]) or "(root)"
    return f"{source}: field '{where}': {err['msg']}"


def load_section(path: str | Path | None, stage: str, overrides: dict | None = None) -> BaseModel:
    """The config section `stage` from a YAML file (defaults when `path` is None), with overrides."""
    sections = _SECTIONS
    if stage not in sections:
        raise TerraError(f"unknown config stage {stage!r}; expected one of: {', '.join(sections)}")
    data: dict = {}
    source = "defaults"
    if path is not None:
        source = str(path)
        data = _read_config(Path(path), sections).get(stage)
        if data is None:
            data = {}
        elif not isinstance(data, dict):
            raise TerraError(
                f"{path}: field '{stage}' must be a mapping of the {stage} section's options "
                f"(see `terra config dump {stage}`), got {type(data).__name__}"
            )
    data = _deep_merge(data, overrides or {})
    try:
        return _section(stage).model_validate(data)
    except ValidationError as exc:
        raise TerraError(validation_message(f"{source} [{stage}]", exc)) from None


def _read_config(path: Path, sections: dict) -> dict:
    """The top-level mapping of a config file; TerraError for unreadable YAML or an unknown key."""
    from terra.fileio import read_yaml

    keys = [*sections, DATASET_KEY]
    raw = read_yaml(path, "config file") or {}
    if not isinstance(raw, dict):
        raise TerraError(f"{path}: expected a mapping with keys among {', '.join(keys)}")
    unknown = [key for key in raw if key not in keys]
    if unknown:
        raise TerraError(
            f"{path}: unknown top-level key {str(unknown[0])[:60]!r}; expected keys among {', '.join(keys)}"
        )
    return raw


def load_dataset_options(path: str | Path | None) -> dict:
    """The `dataset` section of a config file as a plain mapping ({} without one); the loader
    that opens the source validates it against its own options section."""
    if path is None:
        return {}
    options = _read_config(Path(path), _SECTIONS).get(DATASET_KEY) or {}
    if not isinstance(options, dict):
        raise TerraError(f"{path}: field 'dataset' must be a mapping of the loader's options")
    return options


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
    section = load_section(None, stage)
    return yaml.safe_dump({stage: section.model_dump(mode="json")}, sort_keys=False)
