"""The `models` perception backend: the paper's Phase 1 models, each configured by path.

- Terrain: a YOLO segmentation model fine-tuned on terrain classes (or YOLOE with text prompts when
  none exists). Each detection's mask paints its terrain class into the terrain index image, the
  highest-scoring detection last, so it wins where masks overlap.
- Masks: FastSAM (class-agnostic YOLOv8-seg), masks placed on the original image.
- Embeddings: CLIP, for masks, the whole image and the terrain class names (terra/perception/clip.py).

As in the reference, object masks are proposed and embedded on the image with terrain blacked out
(`remove_terrain`), so FastSAM and CLIP see objects rather than ground; the whole-image embedding sees
the full image. An image where nothing is found is a normal frame with no masks.

Weight files run on onnxruntime (`.onnx`, the `yolo-onnx` runtime) or ultralytics (`.pt`, the
optional `ultralytics` runtime). Files are checked, and the terrain classes matched to the model's
names, when the backend is built; networks load on first use.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Protocol

import numpy as np
from scipy import ndimage

from terra.datasets.base import CameraFrame, ClassTable
from terra.errors import TerraError
from terra.perception.base import ImagePerception, Perception
from terra.perception.clip import ClipEmbedder, clip_embedder
from terra.perception.config import PerceptionConfig
from terra.perception.device import Device, resolve_device
from terra.perception.masks import MaskSet
from terra.perception.models_config import MaskModelConfig, ModelsConfig, SegmenterConfig, TerrainModelConfig
from terra.perception.text import register_text_embedder
from terra.perception.weights import ModelFile, require_file
from terra.perception.yolo import DecodeSettings, Detections

FIELD = "perception.models"


class SegmentationModel(Protocol):
    """A segmentation network behind either runtime: class names and detections with masks."""

    files: list[ModelFile]

    @property
    def names(self) -> list[str] | None: ...

    def predict(self, image: np.ndarray, settings: DecodeSettings) -> Detections: ...


def decode_settings(config: SegmenterConfig, agnostic: bool) -> DecodeSettings:
    return DecodeSettings(config.conf, config.iou, config.max_det, config.mask_threshold, config.min_pixels, agnostic)


def load_segmentation_model(
    config: SegmenterConfig, role: str, device: Device, allow_download: bool, prompts: list[str] | None = None
) -> SegmentationModel:
    """The network of a terrain or masks section, on the runtime its file (or `runtime`) asks for."""
    field = f"{FIELD}.{role}.model"
    what = {
        "terrain": "a YOLO segmentation model of the terrain classes (.onnx export or .pt)",
        "masks": "a FastSAM model (.onnx export or FastSAM-s.pt)",
    }[role]
    runtime = config.resolved_runtime()
    if runtime == "yolo-onnx":
        from terra.perception.onnx_yolo import OnnxSegmentationModel

        if prompts:
            raise TerraError(
                f"{FIELD}.{role}.prompts needs runtime ultralytics and a YOLOE .pt model; for ONNX, export "
                "the YOLOE model after set_classes and map its names with perception.models.terrain.classes"
            )
        path = require_file(config.model, field, what, (".onnx",))
        return OnnxSegmentationModel(path, device, role, field, config.names, config.imgsz)
    from terra.perception.ultralytics_yolo import UltralyticsSegmentationModel

    extra = {}
    if isinstance(config, TerrainModelConfig) and prompts:
        for key in ("prompt_embeddings", "text_encoder"):
            value = getattr(config, key)
            extra[key] = (
                None
                if value is None
                else require_file(value, f"{FIELD}.{role}.{key}", f"the YOLOE {key.replace('_', ' ')} file")
            )
    if config.model and allow_download and not Path(config.model).expanduser().is_file():
        path = Path(config.model)  # a model name ultralytics may download (allow_download only)
    else:
        path = require_file(config.model, field, what)
    return UltralyticsSegmentationModel(path, device, role, field, prompts, allow_download=allow_download, **extra)


class ModelTerrainSegmenter:
    """TerrainSegmenter over a segmentation model: terrain index per pixel from its class masks."""

    timed = True

    def __init__(
        self,
        model: SegmentationModel,
        class_to_terrain: np.ndarray,
        terrain_classes: list[str],
        settings: DecodeSettings,
    ):
        self.model = model
        self.class_to_terrain = np.asarray(class_to_terrain, dtype=np.int16)
        self.terrain_classes = list(terrain_classes)
        self.settings = settings
        self.files = list(model.files)

    def segment_terrain(self, camera: CameraFrame, rng: np.random.Generator) -> np.ndarray:
        """(H, W) int16 terrain index per pixel (-1 = not terrain)."""
        found = self.model.predict(np.asarray(camera.image), self.settings)
        return paint_terrain(found, self.class_to_terrain)


def paint_terrain(found: Detections, class_to_terrain: np.ndarray) -> np.ndarray:
    """Terrain index image of detections: lowest score painted first, so the best mask wins overlaps;
    detections of model classes that are not terrain (index -1) are ignored."""
    out = np.full(found.shape, -1, dtype=np.int16)
    for i in np.argsort(found.scores, kind="stable"):
        cls = int(found.classes[i])
        terrain = int(class_to_terrain[cls]) if 0 <= cls < class_to_terrain.size else -1
        if terrain < 0:
            continue
        r0, c0, r1, c1 = found.mask_boxes[i]
        region = out[r0:r1, c0:c1]
        region[found.mask_crops[i]] = terrain
    return out


class ModelMaskProposer:
    """MaskProposer over a class-agnostic segmentation model (FastSAM)."""

    def __init__(self, model: SegmentationModel, settings: DecodeSettings):
        self.model = model
        self.settings = settings
        self.files = list(model.files)

    def propose_masks(self, camera: CameraFrame, rng: np.random.Generator) -> MaskSet:
        found = self.model.predict(np.asarray(camera.image), self.settings)
        return MaskSet(found.shape, found.mask_boxes.reshape(-1, 4), list(found.mask_crops))


def blank_terrain(image: np.ndarray, terrain: np.ndarray, margin_px: int) -> np.ndarray:
    """A copy of the (H, W, 3) image with terrain pixels black, except those within `margin_px` of a
    non-terrain pixel (object boundaries stay intact)."""
    ground = np.asarray(terrain) >= 0
    if margin_px > 0:  # square erosion as a separable minimum filter; beyond the image counts as terrain
        ground = ndimage.minimum_filter(ground.view(np.uint8), size=2 * margin_px + 1, mode="constant", cval=1).view(
            bool
        )
    out = np.array(image, copy=True)
    out[ground] = 0
    return out


class ModelPerception(Perception):
    """Perception whose object masks are proposed and embedded on the terrain-removed image."""

    def __init__(
        self,
        *args,
        remove_terrain: bool = True,
        terrain_margin_px: int = 3,
        terrain_templates: list[str] | None = None,
        **kwargs,
    ):
        super().__init__(*args, **kwargs)
        self.remove_terrain = remove_terrain
        self.terrain_margin_px = terrain_margin_px
        self.terrain_templates = list(terrain_templates or [])

    def perceive(self, camera: CameraFrame, rng: np.random.Generator) -> ImagePerception:
        terrain = self.terrain.segment_terrain(camera, rng)
        view = camera
        if self.remove_terrain:
            view = replace(camera, image=blank_terrain(np.asarray(camera.image), terrain, self.terrain_margin_px))
        masks = self.proposer.propose_masks(view, rng)
        embeddings = self.mask_embedder.embed_masks(view, masks) if len(masks) else np.zeros((0, self.dim), np.float32)
        return ImagePerception(terrain, masks, embeddings, self.image_embedder.embed_image(camera))

    def terrain_embeddings(self) -> np.ndarray:
        embedder = self.mask_embedder
        if isinstance(embedder, ClipEmbedder):
            return embedder.embed_prompts(self.terrain_classes, self.terrain_templates)
        return super().terrain_embeddings()


def map_terrain_classes(
    model_names: list[str] | None, terrain: list[str], wanted: dict[str, str], source: str
) -> np.ndarray:
    """(nc,) terrain index per model class (-1 = not terrain): terrain class t is the model class named
    wanted.get(t, t), compared case-insensitively. TerraError naming what is missing."""
    field = f"{FIELD}.terrain"
    unknown = sorted(set(wanted) - set(terrain))
    if unknown:
        raise TerraError(f"{field}.classes: {unknown[0]!r} is not a terrain class of the map ({', '.join(terrain)})")
    if not model_names:
        raise TerraError(f"{field}: {source} carries no class names; list them in {field}.names")
    index = {}
    for i, name in enumerate(model_names):
        index.setdefault(name.strip().lower(), i)
    out = np.full(len(model_names), -1, dtype=np.int16)
    missing = []
    for t, name in enumerate(terrain):
        target = wanted.get(name, name).strip().lower()
        if target not in index:
            missing.append(name)
            continue
        if out[index[target]] >= 0:
            raise TerraError(
                f"{field}.classes: terrain classes {terrain[out[index[target]]]!r} and {name!r} both map to "
                f"the model class {model_names[index[target]]!r}; give each its own class"
            )
        out[index[target]] = t
    if missing:
        raise TerraError(
            f"{field}: the classes of {source} ({', '.join(model_names)}) do not cover the terrain classes "
            f"{', '.join(map(repr, missing))}; map each to a model class with {field}.classes "
            f"(e.g. {{{missing[0]}: <model class>}}) or list the map's terrain classes in {field}.terrain_classes"
        )
    return out


def terrain_class_names(config: TerrainModelConfig, classes: ClassTable) -> list[str]:
    names = list(config.terrain_classes) if config.terrain_classes else [c.name for c in classes.terrain_classes]
    if not names:
        raise TerraError(
            f"{FIELD}.terrain.terrain_classes: the dataset has no terrain classes; list the map's terrain classes"
        )
    return names


def build_terrain_segmenter(models: ModelsConfig, classes: ClassTable, device: Device) -> ModelTerrainSegmenter:
    """The terrain segmenter of a `models` section for a source with class table `classes`."""
    config = models.terrain
    terrain = terrain_class_names(config, classes)
    prompts = [config.classes.get(t, t) for t in terrain] if config.prompts else None
    model = load_segmentation_model(config, "terrain", device, models.allow_download, prompts)
    if prompts:  # YOLOE's vocabulary is the prompts themselves, in terrain order
        class_to_terrain = np.arange(len(terrain), dtype=np.int16)
    else:
        class_to_terrain = map_terrain_classes(model.names, terrain, config.classes, str(config.model))
    return ModelTerrainSegmenter(model, class_to_terrain, terrain, decode_settings(config, agnostic=False))


def _identity(
    models: ModelsConfig, device: Device, parts: list[ModelFile], embedder: ClipEmbedder, terrain: list[str]
) -> dict:
    """Everything the outputs depend on besides the image: settings (paths replaced by file hashes),
    precision, and the terrain vocabulary."""
    settings = models.model_dump(mode="json", exclude={"device", "allow_download"})
    for section in ("clip", "terrain", "masks"):
        settings[section].pop("model", None)
    settings["terrain"].pop("prompt_embeddings", None)
    settings["terrain"].pop("text_encoder", None)
    return {
        "backend": "models",
        "settings": settings,
        "fp16": device.fp16,
        "embedder": [embedder.name, embedder.dim],
        "terrain_classes": terrain,
        "models": [[m.role, m.name, m.sha256] for m in parts],
    }


def _check_embedder_field(config: PerceptionConfig) -> None:
    if (
        "embedder" in config.model_fields_set
        and config.embedder != PerceptionConfig().embedder
        and not config.embedder.startswith("clip:")
    ):
        raise TerraError(
            f"perception.embedder is {config.embedder!r}, but with backend 'models' the CLIP model "
            "(perception.models.clip.model) embeds masks, images and text in one space; remove perception.embedder"
        )


def models_backend(config: PerceptionConfig, classes: ClassTable) -> Perception:
    """The `models` backend: terrain YOLO, FastSAM masks and CLIP, from `config.models`."""
    models = config.models
    _check_embedder_field(config)
    device = resolve_device(models.device, models.fp16, f"{FIELD}.device")
    embedder = clip_embedder(models.clip, device, models.allow_download)
    terrain = build_terrain_segmenter(models, classes, device)
    masks_config: MaskModelConfig = models.masks
    proposer = ModelMaskProposer(
        load_segmentation_model(masks_config, "masks", device, models.allow_download),
        decode_settings(masks_config, agnostic=True),
    )
    files = [*terrain.files, *proposer.files, *embedder.files]
    perception = ModelPerception(
        terrain,
        proposer,
        embedder,
        embedder,
        backend="models",
        identity=_identity(models, device, files, embedder, terrain.terrain_classes),
        models=files,
        random=False,
        uses_labels=False,
        remove_terrain=models.remove_terrain,
        terrain_margin_px=models.terrain_margin_px,
        terrain_templates=models.clip.terrain_templates,
    )
    # Queries in this process (terra demo, tests) find the embedder by the name the map records.
    register_text_embedder(embedder.name, lambda: embedder)
    return perception


def models_terrain_segmenter(config: PerceptionConfig, classes: ClassTable) -> ModelTerrainSegmenter:
    """Only the terrain segmenter of the `models` backend (terrain evaluation loads neither FastSAM nor CLIP)."""
    models = config.models
    return build_terrain_segmenter(models, classes, resolve_device(models.device, models.fp16, f"{FIELD}.device"))


models_backend.terrain_segmenter = models_terrain_segmenter  # type: ignore[attr-defined]
