"""The `clip` embedder: CLIP (Hugging Face `transformers` CLIPModel) for masks, whole images and text.

Mask embedding follows the paper (and the reference, without its defects): the mask's bounding box
widened by `bbox_margin_px` on every side is cut from the image (RGB, never BGR), every pixel
outside the mask dilated by `mask_dilation_px` is set to black, and the crop gets CLIP's own
preprocessing (shortest side resized with antialiased bicubic, centre crop, the processor's mean
and std); crops go through the image tower in batches of `batch_size`, and every vector is L2
normalised. A whole image is embedded the same way without the mask. A text is embedded alone (its
vector never depends on what else is embedded with it, so maps are byte-reproducible), optionally
as the normalised mean over prompt templates.

The embedder's name, `clip:<folder>@<first 12 hex of the weights' SHA-256>`, encodes model and
weights: a map records it, and queries are refused unless they are embedded by the same weights
(tasks/queries.py). Another process finds those weights again through the folders listed in the
TERRA_CLIP_PATH environment variable (`clip_text_embedder`).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from scipy import ndimage

from terra.datasets.base import CameraFrame
from terra.errors import TerraError
from terra.perception.device import Device, resolve_device
from terra.perception.masks import MaskSet
from terra.perception.models_config import ClipConfig
from terra.perception.text import normalize_rows
from terra.perception.weights import ModelFile, combined_digest, folder_files

if TYPE_CHECKING:
    import torch
    from transformers import CLIPModel, PreTrainedTokenizerBase

NAME_PREFIX = "clip:"
CLIP_PATH_ENV = "TERRA_CLIP_PATH"


def masked_crop(image: np.ndarray, box: np.ndarray, crop: np.ndarray, margin: int, dilation: int) -> np.ndarray:
    """The CLIP input of one mask before preprocessing: (h, w, 3) uint8.

    image: (H, W, 3) uint8 RGB. box: row0, col0, row1, col1 of the mask's crop (end exclusive).
    The window is the box widened by `margin` pixels (clipped to the image); pixels of the window
    outside the mask dilated by `dilation` pixels (square structuring element) are black."""
    height, width = image.shape[:2]
    r0, c0, r1, c1 = (int(v) for v in box)
    top, left = max(r0 - margin, 0), max(c0 - margin, 0)
    bottom, right = min(max(r1, r0 + 1) + margin, height), min(max(c1, c0 + 1) + margin, width)
    window = np.array(image[top:bottom, left:right, :3], dtype=np.uint8)
    keep = np.zeros(window.shape[:2], dtype=bool)
    if crop.size:
        keep[r0 - top : r1 - top, c0 - left : c1 - left] = crop
        if dilation > 0:  # a square dilation is a separable maximum filter: two 1-D passes
            keep = ndimage.maximum_filter(keep.view(np.uint8), size=2 * dilation + 1, mode="constant", cval=0).view(
                bool
            )
    window[~keep] = 0
    return window


class ClipPreprocess:
    """CLIP's image preprocessing, read from the model's image processor, run with torch (batched on
    the model's device): resize so the shortest side is `shortest` (antialiased bicubic, PIL's kernel,
    rounded to 8-bit levels like the processor's uint8 resize), centre crop, rescale, normalise."""

    def __init__(self, processor: object):
        size = getattr(processor, "size", None) or {}
        crop = getattr(processor, "crop_size", None) or {}
        self.shortest = int(size.get("shortest_edge") or min(size.get("height", 224), size.get("width", 224)))
        self.crop = (int(crop.get("height", self.shortest)), int(crop.get("width", self.shortest)))
        self.do_resize = bool(getattr(processor, "do_resize", True))
        self.do_center_crop = bool(getattr(processor, "do_center_crop", True))
        self.scale = (
            float(getattr(processor, "rescale_factor", 1 / 255)) if getattr(processor, "do_rescale", True) else 1.0
        )
        self.normalize = bool(getattr(processor, "do_normalize", True))
        self.mean = np.asarray(
            getattr(processor, "image_mean", None) or [0.48145466, 0.4578275, 0.40821073], np.float32
        )
        self.std = np.asarray(getattr(processor, "image_std", None) or [0.26862954, 0.26130258, 0.27577711], np.float32)

    def resized_shape(self, height: int, width: int) -> tuple[int, int]:
        """(h, w) after the shortest-side resize (the long side truncated, as transformers does)."""
        if not self.do_resize:
            return height, width
        if height <= width:
            return self.shortest, int(self.shortest * width / height)
        return int(self.shortest * height / width), self.shortest

    def __call__(self, images: list[np.ndarray], device: str = "cpu", dtype: torch.dtype | None = None) -> torch.Tensor:
        """(n, 3, crop_h, crop_w) torch tensor from n (h, w, 3) uint8 RGB images."""
        import torch
        import torch.nn.functional as F

        out = []
        for image in images:
            t = (
                torch.tensor(np.asarray(image)[..., :3], device=device).permute(2, 0, 1)[None].float()
            )  # a copy: frames may be read-only
            size = self.resized_shape(*image.shape[:2])
            if size != tuple(image.shape[:2]):
                t = (
                    F.interpolate(t, size=size, mode="bicubic", antialias=True, align_corners=False)
                    .round()
                    .clamp(0, 255)
                )
            if self.do_center_crop:
                t = _center_crop(t, self.crop)
            out.append(t)
        batch = torch.cat(out) * self.scale
        if self.normalize:
            mean = torch.as_tensor(self.mean, device=device).view(1, 3, 1, 1)
            std = torch.as_tensor(self.std, device=device).view(1, 3, 1, 1)
            batch = (batch - mean) / std
        return batch.to(dtype) if dtype is not None else batch


def _center_crop(t: torch.Tensor, crop: tuple[int, int]) -> torch.Tensor:
    """Centre crop of a (1, 3, h, w) tensor to `crop` (zero padding where the image is smaller)."""
    import torch.nn.functional as F

    h, w = t.shape[-2:]
    ch, cw = crop
    if h < ch or w < cw:
        pad_h, pad_w = max(ch - h, 0), max(cw - w, 0)
        t = F.pad(t, (pad_w // 2, pad_w - pad_w // 2, pad_h // 2, pad_h - pad_h // 2))
        h, w = t.shape[-2:]
    top, left = (h - ch) // 2, (w - cw) // 2
    return t[..., top : top + ch, left : left + cw]


def _features(output: object) -> torch.Tensor:
    """Projected features from get_image_features / get_text_features (a tensor in transformers 4, an
    output object with the projection in `pooler_output` in transformers 5)."""
    import torch
    from transformers.modeling_outputs import BaseModelOutputWithPooling

    if isinstance(output, torch.Tensor):
        return output
    if isinstance(output, BaseModelOutputWithPooling) and output.pooler_output is not None:
        return output.pooler_output
    raise TerraError(f"CLIP returned {type(output).__name__} where projected features were expected")


class ClipEmbedder:
    """MaskEmbedder, ImageEmbedder and TextEmbedder of one CLIP model folder.

    `name` encodes the folder and weights; `dim` is the projection dimension; `files` lists the
    model's files (name, size, SHA-256) for the manifest. The network loads on first use, so a map
    fused entirely from the perception cache never loads it."""

    def __init__(self, folder: Path, device: Device, batch_size: int = 32, margin: int = 10, dilation: int = 6):
        from transformers import CLIPConfig

        self.folder = Path(folder)
        self.device = device
        self.batch_size = int(batch_size)
        self.margin = int(margin)
        self.dilation = int(dilation)
        self.files: list[ModelFile] = folder_files(self.folder, "clip")
        if not any(f.name.endswith((".safetensors", ".bin")) for f in self.files):
            raise TerraError(
                f"perception.models.clip.model: {self.folder} holds no weights (model.safetensors or "
                "pytorch_model.bin); give the folder of a CLIP model saved with save_pretrained"
            )
        try:
            projection_dim = CLIPConfig.from_pretrained(str(self.folder), local_files_only=True).projection_dim
        except (OSError, ValueError) as exc:
            raise TerraError(
                f"perception.models.clip.model: {self.folder} is not a CLIP model folder ({exc})"
            ) from None
        if projection_dim is None:
            raise TerraError(f"perception.models.clip.model: {self.folder}: its config.json sets no projection_dim")
        self.dim = int(projection_dim)
        self.digest = combined_digest(self.files)
        self.name = f"{NAME_PREFIX}{self.folder.name.lower()}@{self.digest[:12]}"
        self._model: CLIPModel | None = None
        self._tokenizer: PreTrainedTokenizerBase | None = None
        self._preprocess: ClipPreprocess | None = None
        self._text_cache: dict[str, np.ndarray] = {}

    # -- loading ---------------------------------------------------------------------------

    _dtype: torch.dtype
    """The network's float type (float16 with fp16), set when it loads."""

    def _load(self) -> tuple[CLIPModel, PreTrainedTokenizerBase, ClipPreprocess]:
        """The network, its tokenizer and its preprocessing, loaded on first use."""
        if self._model is None or self._tokenizer is None or self._preprocess is None:
            self._model, self._tokenizer, self._preprocess = self._read_network()
        return self._model, self._tokenizer, self._preprocess

    def _read_network(self) -> tuple[CLIPModel, PreTrainedTokenizerBase, ClipPreprocess]:
        import torch
        from transformers import AutoImageProcessor, AutoTokenizer, CLIPModel

        with _quiet_transformers():
            model = CLIPModel.from_pretrained(str(self.folder), local_files_only=True)
            processor = AutoImageProcessor.from_pretrained(str(self.folder), local_files_only=True)
            tokenizer = AutoTokenizer.from_pretrained(str(self.folder), local_files_only=True)
        # transformers wraps PreTrainedModel.to with functools.wraps, which pyright reads as an
        # unbound function (the device string lands on `self`); the call is Module.to.
        model = model.to(self.device.torch).eval()  # pyright: ignore[reportArgumentType]
        if self.device.fp16:
            model = model.half()
        self._dtype = torch.float16 if self.device.fp16 else torch.float32
        return model, tokenizer, ClipPreprocess(processor)

    @property
    def preprocess(self) -> ClipPreprocess:
        return self._load()[2]

    # -- embeddings ------------------------------------------------------------------------

    def embed_crops(self, crops: list[np.ndarray]) -> np.ndarray:
        """(n, dim) float32 unit vectors of n (h, w, 3) uint8 RGB images, in batches of `batch_size`."""
        import torch

        if not crops:
            return np.zeros((0, self.dim), dtype=np.float32)
        model, _, preprocess = self._load()
        out = []
        with torch.inference_mode():
            for start in range(0, len(crops), self.batch_size):
                pixels = preprocess(crops[start : start + self.batch_size], self.device.torch, self._dtype)
                out.append(_features(model.get_image_features(pixel_values=pixels)).float().cpu().numpy())
        return normalize_rows(np.concatenate(out))

    def mask_crops(self, image: np.ndarray, masks: MaskSet) -> list[np.ndarray]:
        """The masked, widened crops of every mask of an (H, W, 3) uint8 RGB image (before preprocessing)."""
        return [
            masked_crop(image, box, crop, self.margin, self.dilation) for box, crop in zip(masks.boxes, masks.crops)
        ]

    def embed_masks(self, camera: CameraFrame, masks: MaskSet) -> np.ndarray:
        """(M, dim) float32 unit vectors, one per mask of the camera's image."""
        return self.embed_crops(self.mask_crops(np.asarray(camera.image), masks))

    def embed_image(self, camera: CameraFrame) -> np.ndarray:
        """(dim,) float32 unit vector of the whole image."""
        return self.embed_crops([np.asarray(camera.image, dtype=np.uint8)])[0]

    def embed_text(self, texts: list[str]) -> np.ndarray:
        """(n, dim) float32 unit vectors; each text is encoded alone (see the module docstring)."""
        import torch

        if not texts:
            return np.zeros((0, self.dim), dtype=np.float32)
        missing = [t for t in dict.fromkeys(texts) if t not in self._text_cache]
        if missing:
            model, tokenizer, _ = self._load()
            with torch.inference_mode():
                for text in missing:
                    tokens = tokenizer([text], truncation=True, max_length=_context_length(model), return_tensors="pt")
                    tokens = {k: v.to(self.device.torch) for k, v in tokens.items()}
                    vector = _features(model.get_text_features(**tokens)).float().cpu().numpy()
                    self._text_cache[text] = normalize_rows(vector)[0]
        return np.stack([self._text_cache[t] for t in texts]).astype(np.float32)

    def embed_prompts(self, names: list[str], templates: list[str]) -> np.ndarray:
        """(n, dim) unit vectors of class names: the normalised mean over `templates` (each with one {}),
        or the bare names when there are none."""
        if not templates:
            return self.embed_text(names)
        per_template = [self.embed_text([t.format(n) for n in names]) for t in templates]
        return normalize_rows(np.mean(per_template, axis=0))


def _context_length(model: CLIPModel) -> int:
    return int(getattr(model.config.text_config, "max_position_embeddings", 77))


def _quiet_transformers():
    """transformers without bars or warnings while a model loads (terra.perception.quiet)."""
    from terra.perception.quiet import quiet_transformers

    return quiet_transformers()


def resolve_clip_folder(model: str | None, allow_download: bool, field: str = "perception.models.clip.model") -> Path:
    """The local folder of the configured CLIP model; a hub id is fetched only with allow_download."""
    if not model:
        raise TerraError(
            f"{field} is not set: give the folder of a CLIP model saved with save_pretrained "
            "(e.g. a local copy of openai/clip-vit-base-patch16)"
        )
    folder = Path(model).expanduser()
    if folder.is_dir():
        return folder
    if folder.exists():
        raise TerraError(f"{field}: {folder} is a file; give the folder of a CLIP model saved with save_pretrained")
    if not allow_download:
        raise TerraError(
            f"{field}: folder {folder} not found; give the folder of a CLIP model saved with save_pretrained "
            "(or set perception.models.allow_download: true to fetch a hub id)"
        )
    try:
        from huggingface_hub import snapshot_download

        return Path(snapshot_download(repo_id=str(model)))
    except Exception as exc:  # any hub failure (offline, unknown id) is the user's to fix
        raise TerraError(f"{field}: could not download {model!r} ({type(exc).__name__}: {exc})") from None


def clip_embedder(config: ClipConfig, device: Device | None = None, allow_download: bool = False) -> ClipEmbedder:
    """The CLIP embedder of a `clip` config section (the factory of the `models` backend's embedder)."""
    folder = resolve_clip_folder(config.model, allow_download)
    return ClipEmbedder(
        folder, device or resolve_device("auto"), config.batch_size, config.bbox_margin_px, config.mask_dilation_px
    )


def _candidate_folders(label: str) -> list[Path]:
    """Folders named in TERRA_CLIP_PATH (each a model folder or a folder of model folders), those named
    `label` first."""
    found: list[Path] = []
    for entry in filter(None, os.environ.get(CLIP_PATH_ENV, "").split(os.pathsep)):
        root = Path(entry).expanduser()
        if (root / "config.json").is_file():
            found.append(root)
        elif root.is_dir():
            found.extend(sorted(p for p in root.iterdir() if (p / "config.json").is_file()))
    return sorted(dict.fromkeys(found), key=lambda p: p.name.lower() != label)


# CLIP ViT-B/16 (openai/clip-vit-base-patch16): the architecture that identifies it in a config.json
VIT_B16 = {"projection_dim": 512, "image_size": 224, "patch_size": 16, "vision_hidden": 768, "text_hidden": 512}


def is_vit_b16(folder: Path) -> bool:
    """Whether the CLIP model folder `folder` has CLIP ViT-B/16's architecture (its config.json)."""
    from transformers import CLIPConfig

    try:
        config = CLIPConfig.from_pretrained(str(folder), local_files_only=True)
    except (OSError, ValueError):
        return False
    vision, text = config.vision_config, config.text_config  # typed loosely by transformers' stubs
    found = {
        "projection_dim": config.projection_dim,
        "image_size": getattr(vision, "image_size", None),
        "patch_size": getattr(vision, "patch_size", None),
        "vision_hidden": getattr(vision, "hidden_size", None),
        "text_hidden": getattr(text, "hidden_size", None),
    }
    return found == VIT_B16


def vit_b16_text_embedder() -> ClipEmbedder:
    """Text embedder `clip-vit-b-16`: OpenAI CLIP ViT-B/16, the model the authors' map files are made
    with (`terra import` names it for their files), from a CLIP model folder of that architecture in
    TERRA_CLIP_PATH (the `models` perception backend's CLIP model, saved with save_pretrained)."""
    from terra.perception.text import REFERENCE_CLIP_EMBEDDER

    for folder in _candidate_folders("clip-vit-base-patch16"):
        if is_vit_b16(folder):
            embedder = ClipEmbedder(folder, resolve_device("auto", fp16=False))
            embedder.name = REFERENCE_CLIP_EMBEDDER
            return embedder
    looked = f"no folder in {CLIP_PATH_ENV} is one" if os.environ.get(CLIP_PATH_ENV) else f"{CLIP_PATH_ENV} is not set"
    raise TerraError(
        f"text embedder {REFERENCE_CLIP_EMBEDDER!r} (OpenAI CLIP ViT-B/16, the authors' model) needs its weights "
        f"({looked}): save openai/clip-vit-base-patch16 with save_pretrained, the CLIP model folder the `models` "
        f"perception backend uses, and set {CLIP_PATH_ENV} to it"
    )


def clip_text_embedder(name: str) -> ClipEmbedder:
    """The CLIP embedder called `name` (clip:<folder>@<digest>), found through TERRA_CLIP_PATH; used to
    embed queries for a map built with the `models` backend in another process."""
    label, _, digest = name[len(NAME_PREFIX) :].rpartition("@")
    for folder in _candidate_folders(label):
        if combined_digest(folder_files(folder, "clip"))[: len(digest)] == digest:
            return ClipEmbedder(folder, resolve_device("auto", fp16=False))
    raise TerraError(
        f"embedder {name!r}: no CLIP model folder with these weights (SHA-256 {digest}...) was found; set "
        f"{CLIP_PATH_ENV} to the folder holding the CLIP model '{label}' the map was built with"
    )
