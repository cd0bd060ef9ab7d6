"""Phase 1 perception alone: fill the per-frame perception cache without fusing (`terra map --perception-only`).

`perceive_frame` is the unit of work: frame i of a dataset, every usable image of it, perceived into
the cache. It takes everything it uses as arguments (dataset, cached perception, mapping config) and
keeps no state between calls, so any number of processes (e.g. Dask workers, each with its own
CachedPerception on a shared cache folder) can run it on different frames; `terra map` afterwards
reads every image back without running a model. Images are perceived with the same generator
([noise seed, frame, camera]) and skipped for the same faults as when mapping, so the cache holds
exactly what fusion will ask for.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from terra.datasets.base import Dataset
from terra.errors import TerraError
from terra.mapping.config import MappingConfig
from terra.mapping.fusion import FusionStats
from terra.mapping.mapper import perceive_image, uses_images
from terra.mapping.pipeline import load_frame, open_perception
from terra.perception.base import Perception
from terra.perception.cache import CachedPerception
from terra.progress import StageTimer
from terra.progress import progress as progress_bar


@dataclass
class PerceptionRun:
    """What `run_perception` did: cache folder, frames and images seen, images read back (hits) and
    computed, fault counters with a first example each, stage timings."""

    folder: Path
    frames: int
    images: int
    hits: int
    computed: int
    stats: dict[str, int] = field(default_factory=dict)
    notes: dict[str, str] = field(default_factory=dict)
    timer: StageTimer = field(default_factory=StageTimer)


def perceive_frame(
    dataset: Dataset, index: int, perception: CachedPerception, config: MappingConfig, stats: FusionStats | None = None
) -> int:
    """Perceive every usable image of frame `index` into `perception`'s cache; returns how many images
    were perceived (read back or computed). Faults are counted in `stats` when given, as fusion counts them."""
    stats = stats if stats is not None else FusionStats()
    frame = load_frame(dataset, index, stats)
    if frame is None or not uses_images(frame, config):
        return 0  # scans mapped from per-point labels: nothing to cache
    seen = (perceive_image(perception, frame, index, c, config, stats) for c in range(len(frame.cameras)))
    return sum(image is not None for image in seen)


def run_perception(
    dataset: Dataset, config: MappingConfig, out: Path, show_progress: bool = True, perception: Perception | None = None
) -> PerceptionRun:
    """Fill the perception cache of the bundle `out` (or of `perception.cache.folder`) for every frame."""
    timer = StageTimer()
    if len(dataset) == 0:
        raise TerraError(f"dataset {dataset.name!r} has no frames")
    with timer.stage("setup"):
        cached = open_perception(config, dataset, Path(out), perception)
    if not isinstance(cached, CachedPerception):
        raise TerraError(
            "--perception-only fills the perception cache, which mapping.perception.cache.mode: off "
            "switches off (use on, or auto with a model backend)"
        )
    stats = FusionStats()
    images = 0
    for i in progress_bar(
        range(len(dataset)), desc="perception", total=len(dataset), enabled=show_progress, unit="frames"
    ):
        with timer.stage("perception"):
            images += perceive_frame(dataset, i, cached, config, stats)
    return PerceptionRun(
        cached.cache.folder,
        len(dataset),
        images,
        cached.counts.hits,
        cached.counts.computed,
        stats.to_json(),
        dict(stats.notes),
        timer,
    )
