"""Perception noise for label-driven perception: bleeding masks, missed objects, look-alike swaps.

Every random draw comes from the generator passed in, which the pipeline seeds per (frame,
camera), so a map is the same whatever order (or resumption) its frames were fused in.
"""

from __future__ import annotations

import numpy as np

from terra.datasets.base import ClassTable
from terra.perception.config import NoiseConfig
from terra.perception.masks import MaskSet


class PerceptionNoise:
    """Applies a NoiseConfig to terrain index images, mask sets and labelled point groups."""

    def __init__(self, config: NoiseConfig, classes: ClassTable):
        self.config = config
        terrain = classes.terrain_classes
        terrain_index = {c.name: i for i, c in enumerate(terrain)}
        names = {c.name: c.id for c in classes}
        # Look-alikes as dense tables: object class id -> candidate ids; terrain index -> indices.
        self._object_alikes: dict[int, np.ndarray] = {}
        self._terrain_alikes: dict[int, np.ndarray] = {}
        for name, alikes in sorted(config.confusions.items()):
            if name not in names:
                continue
            if name in terrain_index:
                found = [terrain_index[a] for a in alikes if a in terrain_index]
                if found:
                    self._terrain_alikes[terrain_index[name]] = np.asarray(found, dtype=np.int64)
            else:
                found = [names[a] for a in alikes if a in names and a not in terrain_index]
                if found:
                    self._object_alikes[names[name]] = np.asarray(found, dtype=np.int64)

    @property
    def enabled(self) -> bool:
        return self.config.enabled

    def confuse_terrain(self, terrain: np.ndarray, n_terrain: int, rng: np.random.Generator) -> np.ndarray:
        """Per image, each terrain class is swapped for a look-alike with the confusion rate."""
        draws = rng.random(n_terrain)
        picks = rng.random(n_terrain)
        if self.config.confusion_rate <= 0:
            return terrain
        remap = np.arange(-1, n_terrain, dtype=np.int16)  # index t + 1 -> new terrain index
        for t, alikes in self._terrain_alikes.items():
            if draws[t] < self.config.confusion_rate:
                remap[t + 1] = alikes[int(picks[t] * len(alikes))]
        return remap[terrain.astype(np.int64) + 1]

    def perturb_classes(self, class_ids: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """(keep mask, new class ids) for M labelled groups: misses and look-alike swaps."""
        m = class_ids.shape[0]
        miss, swap, pick = rng.random(m), rng.random(m), rng.random(m)
        keep = miss >= self.config.miss_rate
        out = class_ids.copy()
        for i in np.flatnonzero(swap < self.config.confusion_rate):
            alikes = self._object_alikes.get(int(class_ids[i]))
            if alikes is not None:
                out[i] = alikes[int(pick[i] * len(alikes))]
        return keep, out

    def perturb_masks(self, masks: MaskSet, rng: np.random.Generator) -> MaskSet:
        """Drop missed masks, swap classes, then dilate the rest by `dilate_px`."""
        if not self.enabled or len(masks) == 0 or masks.class_ids is None:
            return masks.dilated(self.config.dilate_px)
        keep, classes = self.perturb_classes(masks.class_ids, rng)
        kept = MaskSet(masks.shape, masks.boxes, masks.crops, classes).subset(np.flatnonzero(keep))
        return kept.dilated(self.config.dilate_px)
