"""Perception protocols: what Phase 1 asks of an image (or of a labelled scan).

A backend is four small parts, each replaceable (a YOLO terrain segmenter, FastSAM proposals,
CLIP crops and CLIP whole-image embeddings slot in behind the same names):

- TerrainSegmenter: image -> (H, W) terrain index per pixel (-1 = not terrain).
- MaskProposer: image -> class-agnostic MaskSet.
- MaskEmbedder: masks of an image, and text -> unit vectors in one embedding space.
- ImageEmbedder: whole image -> one unit vector in the same space.

`Perception` composes them. Every output embedding is a float32 unit row of the embedder's space,
whose name and dimension every map records.

A part that meets an image it cannot perceive by design (the labels backend and an image without
label images) raises `PerceptionSkip`: the mapper skips that image and counts it. Any other
exception is a failure, and stops the run.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from terra.datasets.base import CameraFrame, Frame
from terra.perception.masks import MaskSet


class PerceptionSkip(Exception):
    """This image cannot be perceived, skip it: its message says why (one line, naming the image)."""


@runtime_checkable
class TerrainSegmenter(Protocol):
    terrain_classes: list[str]

    def segment_terrain(self, camera: CameraFrame, rng: np.random.Generator) -> np.ndarray:
        """(H, W) int16 index into `terrain_classes` per pixel; -1 where no terrain."""
        ...


@runtime_checkable
class MaskProposer(Protocol):
    def propose_masks(self, camera: CameraFrame, rng: np.random.Generator) -> MaskSet:
        """Class-agnostic masks of the image (may overlap)."""
        ...


@runtime_checkable
class MaskEmbedder(Protocol):
    name: str
    dim: int

    def embed_masks(self, camera: CameraFrame, masks: MaskSet) -> np.ndarray:
        """(M, dim) float32 unit vectors, one per mask."""
        ...

    def embed_text(self, texts: list[str]) -> np.ndarray:
        """(n, dim) float32 unit vectors, one per text, in the masks' space."""
        ...


@runtime_checkable
class ImageEmbedder(Protocol):
    def embed_image(self, camera: CameraFrame) -> np.ndarray:
        """(dim,) float32 unit vector of the whole image."""
        ...


@dataclass
class ImagePerception:
    """What one image contributes: terrain index image (H, W) int16 (-1 = none), object masks with
    their embeddings (M, D), and the whole-image embedding (D,)."""

    terrain: np.ndarray
    masks: MaskSet
    mask_embeddings: np.ndarray
    image_embedding: np.ndarray


@dataclass
class PointPerception:
    """What a labelled scan without images contributes, per scan point.

    terrain: (n,) int16 terrain index per point (-1 = none). group_point, group_index: pairs
    (point index, group index) of points belonging to object groups (labelled instances).
    group_embeddings: (G, D) one unit vector per group.
    """

    terrain: np.ndarray
    group_point: np.ndarray
    group_index: np.ndarray
    group_embeddings: np.ndarray


@runtime_checkable
class PointLabeler(Protocol):
    def perceive_points(self, frame: Frame, rng: np.random.Generator) -> PointPerception | None:
        """Semantics straight from per-point labels; None when the frame has none."""
        ...


class Perception:
    """A perception backend assembled from its four parts (plus, optionally, a point labeler).

    `embedder` names the embedding space (recorded in the map); `dim` its dimension.
    What the perception cache and the manifest need to know about it:
    backend: its registered name. identity: JSON-able description of everything its outputs depend
    on besides the image (settings, model hashes); the cache keys entries by it. models: the weight
    files it runs (role, name, size, SHA-256). random: whether outputs depend on the generator passed
    to `perceive` (noise); uses_labels: whether they depend on the camera's label images.
    """

    def __init__(
        self,
        terrain: TerrainSegmenter,
        proposer: MaskProposer,
        mask_embedder: MaskEmbedder,
        image_embedder: ImageEmbedder,
        point_labeler: PointLabeler | None = None,
        *,
        backend: str = "custom",
        identity: dict | None = None,
        models: list | None = None,
        random: bool = True,
        uses_labels: bool = True,
    ):
        self.terrain = terrain
        self.proposer = proposer
        self.mask_embedder = mask_embedder
        self.image_embedder = image_embedder
        self.point_labeler = point_labeler
        self.backend = backend
        self.identity = dict(identity or {})
        self.models = list(models or [])
        self.random = random
        self.uses_labels = uses_labels

    def describe(self) -> dict:
        """What the manifest records about this perception: backend, embedder and model files."""
        return {
            "backend": self.backend,
            "embedder": {"name": self.embedder, "dim": self.dim},
            "models": [m.to_json() for m in self.models],
        }

    @property
    def embedder(self) -> str:
        return self.mask_embedder.name

    @property
    def dim(self) -> int:
        return int(self.mask_embedder.dim)

    @property
    def terrain_classes(self) -> list[str]:
        return list(self.terrain.terrain_classes)

    def terrain_embeddings(self) -> np.ndarray:
        """(T, D) text embeddings of the terrain class names."""
        return self.mask_embedder.embed_text(self.terrain_classes)

    def perceive(self, camera: CameraFrame, rng: np.random.Generator) -> ImagePerception:
        terrain = self.terrain.segment_terrain(camera, rng)
        masks = self.proposer.propose_masks(camera, rng)
        embeddings = (
            self.mask_embedder.embed_masks(camera, masks) if len(masks) else np.zeros((0, self.dim), np.float32)
        )
        return ImagePerception(terrain, masks, embeddings, self.image_embedder.embed_image(camera))

    def perceive_points(self, frame: Frame, rng: np.random.Generator) -> PointPerception | None:
        if self.point_labeler is None:
            return None
        return self.point_labeler.perceive_points(frame, rng)
