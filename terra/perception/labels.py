"""The `labels` perception backend: masks and classes from a dataset's own labels.

Where no model weights exist (simulator, SemanticKITTI), terrain masks come from the semantic
image, object masks from the instance image (one mask per instance; one per class for labelled
pixels without an instance, such as building walls), and each mask is embedded as the text
embedding of its class name with the offline sentence model. The whole-image embedding is the
pixel-share-weighted mean of the visible classes' name embeddings, normalised. For scans without
images, the same comes from per-point labels.
"""

from __future__ import annotations

import numpy as np

from terra.datasets.base import CameraFrame, ClassTable, Frame
from terra.perception.base import Perception, PerceptionSkip, PointPerception
from terra.perception.config import PerceptionConfig
from terra.perception.masks import MaskSet
from terra.perception.noise import PerceptionNoise
from terra.perception.text import TextEmbedder, get_text_embedder, normalize_rows


class ClassLookup:
    """Dense lookups over a ClassTable's ids: terrain index and object flag per class id."""

    def __init__(self, classes: ClassTable):
        self.classes = classes
        self.size = max(c.id for c in classes) + 1
        self.terrain_names = [c.name for c in classes.terrain_classes]
        self.terrain_of = np.full(self.size, -1, dtype=np.int16)
        for i, c in enumerate(classes.terrain_classes):
            self.terrain_of[c.id] = i
        # Objects: every labelled class that is not terrain (id 0 is 'unlabeled': sky, nothing).
        self.is_object = np.zeros(self.size, dtype=bool)
        for c in classes:
            self.is_object[c.id] = c.id != 0 and not c.terrain

    def clean(self, ids: np.ndarray) -> np.ndarray:
        """Ids with anything outside the table replaced by 0 (unlabeled), as int64."""
        ids = np.asarray(ids, dtype=np.int64)
        return np.where((ids >= 0) & (ids < self.size), ids, 0)

    def group_keys(self, semantic: np.ndarray, instance: np.ndarray | None) -> np.ndarray:
        """Per pixel or point: 0 = no object, a class id (< size) for instance-less labelled
        object pixels, size + instance id for instances."""
        semantic = self.clean(semantic)
        obj = self.is_object[semantic]
        if instance is None:
            return np.where(obj, semantic, 0)
        instance = np.asarray(instance, dtype=np.int64)
        return np.where(obj, np.where(instance > 0, instance + self.size, semantic), 0)

    def compact_groups(self, keys: np.ndarray, semantic: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Group numbers 1..G per element (0 = none), ordered by key, and each group's majority
        class id (G,)."""
        flat = keys.ravel()
        if flat.size and flat.max() > 4 * flat.size + (1 << 16):
            # Sparse huge instance ids: sort-based numbering instead of a huge bincount.
            uniq, inverse = np.unique(flat, return_inverse=True)
            number = np.cumsum(uniq > 0) * (uniq > 0)
            numbers = number[inverse].reshape(keys.shape)
        else:
            present = np.bincount(flat, minlength=1) > 0
            present[0] = False
            number = np.cumsum(present) * present
            numbers = number[flat].reshape(keys.shape)
        groups = int(number.max(initial=0))
        sem = self.clean(semantic).ravel()
        votes = np.bincount(numbers.ravel() * self.size + sem, minlength=(groups + 1) * self.size)
        votes = votes.reshape(groups + 1, self.size)[1:]
        votes[:, ~self.is_object] = 0
        return numbers, votes.argmax(axis=1).astype(np.int64)


class LabelTerrainSegmenter:
    """Terrain index per pixel from the semantic image, with optional look-alike confusion.

    A table lookup, not a model: `timed` is False so evaluation reports no frame rate for it."""

    timed = False

    def __init__(self, lookup: ClassLookup, noise: PerceptionNoise):
        self.lookup = lookup
        self.noise = noise
        self.terrain_classes = lookup.terrain_names

    def segment_terrain(self, camera: CameraFrame, rng: np.random.Generator) -> np.ndarray:
        terrain = self.lookup.terrain_of[self.lookup.clean(_semantic(camera))]
        return self.noise.confuse_terrain(terrain, len(self.terrain_classes), rng)


class LabelMaskProposer:
    """One mask per labelled instance (and per class for instance-less object pixels)."""

    def __init__(self, lookup: ClassLookup, noise: PerceptionNoise):
        self.lookup = lookup
        self.noise = noise

    def propose_masks(self, camera: CameraFrame, rng: np.random.Generator) -> MaskSet:
        semantic = _semantic(camera)
        keys = self.lookup.group_keys(semantic, camera.instance)
        numbers, class_ids = self.lookup.compact_groups(keys, semantic)
        return self.noise.perturb_masks(MaskSet.from_label_image(numbers, class_ids), rng)


class LabelEmbedder:
    """Embeds masks by their class name and images by their visible classes (one text space)."""

    def __init__(self, lookup: ClassLookup, text: TextEmbedder):
        self.lookup = lookup
        self.text = text
        self.name = text.name
        self.dim = int(text.dim)
        self.class_embeddings = np.zeros((lookup.size, self.dim), dtype=np.float32)
        named = [c for c in lookup.classes if c.id != 0]
        if named:
            self.class_embeddings[[c.id for c in named]] = text.embed_text([c.name for c in named])

    def embed_text(self, texts: list[str]) -> np.ndarray:
        return self.text.embed_text(texts)

    def embed_masks(self, camera: CameraFrame, masks: MaskSet) -> np.ndarray:
        if masks.class_ids is None:
            raise ValueError("the labels embedder needs masks carrying class ids (from the labels proposer)")
        return self.class_embeddings[masks.class_ids]

    def embed_class_ids(self, class_ids: np.ndarray) -> np.ndarray:
        return self.class_embeddings[class_ids]

    def embed_image(self, camera: CameraFrame) -> np.ndarray:
        share = np.bincount(self.lookup.clean(_semantic(camera)).ravel(), minlength=self.lookup.size).astype(np.float64)
        share[0] = 0.0
        return normalize_rows((share @ self.class_embeddings)[None, :])[0]


class LabelPointLabeler:
    """Terrain per point and one group per labelled instance, from a scan's point labels."""

    def __init__(self, lookup: ClassLookup, embedder: LabelEmbedder, noise: PerceptionNoise):
        self.lookup = lookup
        self.embedder = embedder
        self.noise = noise

    def perceive_points(self, frame: Frame, rng: np.random.Generator) -> PointPerception | None:
        if frame.point_labels is None:
            return None
        labels = self.lookup.clean(frame.point_labels)
        terrain = self.lookup.terrain_of[labels]
        terrain = self.noise.confuse_terrain(terrain, len(self.lookup.terrain_names), rng)
        numbers, class_ids = self.lookup.compact_groups(self.lookup.group_keys(labels, frame.point_instances), labels)
        keep, class_ids = (
            self.noise.perturb_classes(class_ids, rng)
            if self.noise.enabled
            else (np.ones(len(class_ids), bool), class_ids)
        )
        kept_number = np.concatenate([[0], np.where(keep, np.cumsum(keep), 0)])  # old number -> new (0 = dropped)
        numbers = kept_number[numbers]
        points = np.flatnonzero(numbers)
        return PointPerception(
            terrain=terrain,
            group_point=points.astype(np.int64),
            group_index=(numbers[points] - 1).astype(np.int64),
            group_embeddings=self.embedder.embed_class_ids(class_ids[keep]),
        )


def _semantic(camera: CameraFrame) -> np.ndarray:
    if camera.semantic is None:
        raise PerceptionSkip(
            f"camera image {camera.name or camera.calibration.name!r} has no semantic labels "
            "(the labels backend needs them)"
        )
    return camera.semantic


def labels_backend(config: PerceptionConfig, classes: ClassTable, text: TextEmbedder | None = None) -> Perception:
    """The `labels` backend for a source's class table."""
    lookup = ClassLookup(classes)
    noise = PerceptionNoise(config.noise, classes)
    embedder = LabelEmbedder(lookup, text if text is not None else get_text_embedder(config.embedder))
    identity = {
        "backend": "labels",
        "embedder": [embedder.name, embedder.dim],
        "noise": config.noise.model_dump(mode="json"),
        "classes": classes.to_json(),
    }
    return Perception(
        terrain=LabelTerrainSegmenter(lookup, noise),
        proposer=LabelMaskProposer(lookup, noise),
        mask_embedder=embedder,
        image_embedder=embedder,
        point_labeler=LabelPointLabeler(lookup, embedder, noise),
        backend="labels",
        identity=identity,
        random=noise.enabled,
        uses_labels=True,
    )
