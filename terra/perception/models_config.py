"""Configuration of the `models` perception backend: each model by path, plus device and thresholds.

Selected with `mapping.perception.backend: models`; the section lives at `mapping.perception.models`.
Paths are read relative to the working directory. Nothing is checked against the disk here (so
`terra config dump` works anywhere); the backend's factory raises a TerraError naming the field
when a file is missing.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Literal

from pydantic import Field, field_validator

from terra.schemas import Section

Runtime = Literal["auto", "yolo-onnx", "ultralytics"]


class ClipConfig(Section):
    """The CLIP embedder of masks, whole images and text (Hugging Face `transformers`)."""

    model: str | None = Field(
        default=None,
        description="folder of a CLIP model saved with save_pretrained (config.json, weights, tokenizer and "
        "preprocessor files), e.g. a local copy of openai/clip-vit-base-patch16; a hub id only with allow_download",
    )
    batch_size: int = Field(default=32, ge=1, le=1024, description="mask crops per forward pass")
    bbox_margin_px: int = Field(
        default=10, ge=0, le=200, description="pixels the mask's bounding box is widened by on every side (paper: 10)"
    )
    mask_dilation_px: int = Field(
        default=6,
        ge=0,
        le=100,
        description="pixels the mask is dilated by (square) before everything outside it is blacked out "
        "(the reference dilates 3 times with a 5 x 5 kernel: 6 px)",
    )
    terrain_templates: list[str] = Field(
        default_factory=list,
        description="prompt templates for the terrain class names, each with one {}; the class embedding is the "
        "normalised mean over templates (empty: the bare name)",
    )

    @field_validator("terrain_templates")
    @classmethod
    def _one_slot(cls, templates: list[str]) -> list[str]:
        for t in templates:
            if t.count("{}") != 1:
                raise ValueError(f"template {t!r} must contain exactly one {{}} for the class name")
        return templates


class SegmenterConfig(Section):
    """A YOLO segmentation model (ultralytics export) used for terrain or for class-agnostic masks."""

    model: str | None = Field(
        default=None, description="weight file: an ultralytics segmentation export (.onnx) or checkpoint (.pt)"
    )
    names: list[str] | None = Field(
        default=None, description="the model's class names in index order, for exports without `names` metadata"
    )
    runtime: Runtime = Field(
        default="auto",
        description="yolo-onnx (onnxruntime), ultralytics (the [ultralytics] extra), auto = by file suffix",
    )
    imgsz: list[int] | None = Field(
        default=None,
        description="network input [height, width] for exports with dynamic input size (default: the export's "
        "own imgsz metadata, else 640 x 640)",
    )
    conf: float = Field(default=0.25, ge=0.0, le=1.0, description="minimum class score of a detection")
    iou: float = Field(
        default=0.7, gt=0.0, le=1.0, description="IoU above which non-maximum suppression drops the weaker box"
    )
    max_det: int = Field(default=100, ge=1, le=10000, description="detections kept per image after NMS")
    mask_threshold: float = Field(
        default=0.5,
        gt=0.0,
        lt=1.0,
        description="mask probability at or below which a pixel is off (yolo-onnx; ultralytics uses 0.5)",
    )
    min_pixels: int = Field(default=1, ge=1, description="masks with fewer pixels in the original image are dropped")

    @field_validator("imgsz")
    @classmethod
    def _imgsz(cls, value: list[int] | None) -> list[int] | None:
        if value is None:
            return None
        if len(value) == 1:
            value = [value[0], value[0]]
        if len(value) != 2 or min(value) < 32 or any(v % 32 for v in value):
            raise ValueError("expected [height, width], multiples of 32 (or one number for a square input)")
        return value

    def resolved_runtime(self) -> str:
        """yolo-onnx or ultralytics (auto: .onnx files run on onnxruntime, anything else on ultralytics)."""
        if self.runtime != "auto":
            return self.runtime
        return "yolo-onnx" if str(self.model or "").lower().endswith(".onnx") else "ultralytics"


class TerrainModelConfig(SegmenterConfig):
    """The terrain segmenter: a YOLO-seg model fine-tuned on terrain classes, or YOLOE with prompts."""

    classes: dict[str, str] = Field(
        default_factory=dict,
        description="terrain class -> the model's class name (or, for YOLOE, the text prompt) that segments it; "
        "terrain classes not listed are looked up by their own name (case-insensitive)",
    )
    terrain_classes: list[str] | None = Field(
        default=None, description="terrain classes of the map in index order (default: the dataset's terrain classes)"
    )
    prompts: bool = Field(
        default=False, description="YOLOE: set the model's vocabulary to the prompts of `classes` (runtime ultralytics)"
    )
    prompt_embeddings: str | None = Field(
        default=None,
        description="YOLOE: .npz of prompt embeddings saved by ultralytics' save_prompt_embeddings (offline "
        "alternative to the MobileCLIP text encoder)",
    )
    text_encoder: str | None = Field(
        default=None,
        description="YOLOE: the MobileCLIP text encoder file ultralytics embeds prompts with (mobileclip_blt.ts)",
    )


class MaskModelConfig(SegmenterConfig):
    """Class-agnostic mask proposals (FastSAM, a YOLOv8-seg with one class). Defaults follow the reference's
    FastSAM call (conf 0.003, iou 0.25, up to 100 masks); masks under 50 pixels carry too few LiDAR points."""

    conf: float = Field(default=0.003, ge=0.0, le=1.0, description="minimum score of a mask")
    iou: float = Field(
        default=0.25, gt=0.0, le=1.0, description="IoU above which non-maximum suppression drops the weaker box"
    )
    min_pixels: int = Field(default=50, ge=1, description="masks with fewer pixels in the original image are dropped")


class ModelsConfig(Section):
    """The `models` backend: YOLO terrain segmentation, FastSAM masks and CLIP embeddings, by path."""

    device: str = Field(default="auto", description="auto (CUDA when available), cpu, cuda or cuda:N")
    fp16: bool = Field(
        default=True,
        description="CLIP (and ultralytics models) in half precision on a GPU, ignored on the CPU; ONNX exports "
        "run in the precision they were exported in (export with half=True for fp16)",
    )
    allow_download: bool = Field(
        default=False, description="let a model name that is not a local path download (never by default)"
    )
    remove_terrain: bool = Field(
        default=True,
        description="black out terrain (eroded by terrain_margin_px) before proposing and embedding object "
        "masks, as the reference does, so FastSAM and CLIP see the objects rather than the ground",
    )
    terrain_margin_px: int = Field(
        default=3, ge=0, le=100, description="terrain pixels this close to non-terrain stay visible"
    )
    clip: ClipConfig = Field(default_factory=ClipConfig)
    terrain: TerrainModelConfig = Field(default_factory=TerrainModelConfig)
    masks: MaskModelConfig = Field(default_factory=MaskModelConfig)

    @field_validator("device")
    @classmethod
    def _device(cls, value: str) -> str:
        if not re.fullmatch(r"auto|cpu|cuda(:\d+)?", value):
            raise ValueError("expected auto, cpu, cuda or cuda:N")
        return value


def model_path(value: str | None) -> Path | None:
    """A configured path with `~` expanded (None stays None)."""
    return None if value is None else Path(value).expanduser()
