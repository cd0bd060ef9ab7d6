"""The `ultralytics` runtime: segmentation checkpoints (.pt) and YOLOE with text prompts, offline.

Optional (`pip install "terra-3dsg[ultralytics]"`); ultralytics needs torchvision. Before it is
imported, the environment is set so it never reaches the network or changes the machine:
YOLO_OFFLINE=1 (no online checks or downloads), YOLO_AUTOINSTALL=0 (no pip installs), a private
YOLO_CONFIG_DIR (its settings file lives there, not in the user's home), and settings sync off.
Weight names that are not local files are refused unless `allow_download` is set.

ultralytics reads numpy images as BGR (OpenCV's order), so the RGB frames Terra holds are flipped on
the way in; its retina masks are already placed on the original image through the letterbox.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from types import ModuleType
from typing import Any, Protocol

import numpy as np

from terra.errors import TerraError
from terra.perception.device import Device
from terra.perception.weights import ModelFile, weight_file
from terra.perception.yolo import DecodeSettings, Detections

INSTALL_HINT = 'pip install "terra-3dsg[ultralytics]" (it needs a working torchvision)'


# What Terra reads of ultralytics' objects (the package is an optional extra, so these are typed by shape).
class _Tensor(Protocol):
    def cpu(self) -> _Tensor: ...

    def numpy(self) -> np.ndarray: ...


class _Masks(Protocol):
    data: _Tensor


class _Boxes(Protocol):
    xyxy: _Tensor
    conf: _Tensor
    cls: _Tensor

    def __len__(self) -> int: ...


class _Results(Protocol):
    masks: _Masks | None
    boxes: _Boxes | None


class _Model(Protocol):
    names: dict[int, str] | list[str]

    def predict(self, source: np.ndarray, **settings: Any) -> list[_Results]: ...

    def set_classes(self, classes: list[str]) -> None: ...


def _offline_environment(allow_download: bool) -> None:
    os.environ["YOLO_OFFLINE"] = "0" if allow_download else "1"
    os.environ["YOLO_AUTOINSTALL"] = "0"
    os.environ.setdefault("YOLO_CONFIG_DIR", str(Path(tempfile.gettempdir()) / "terra-ultralytics"))
    os.environ.setdefault("YOLO_VERBOSE", "False")


def import_ultralytics(field: str, allow_download: bool = False) -> ModuleType:
    """The ultralytics module, imported offline; TerraError with the reason when it cannot be."""
    _offline_environment(allow_download)
    try:
        # An optional extra (terra-3dsg[ultralytics]), absent where the code checks run.
        import ultralytics  # pyright: ignore[reportMissingImports]
        from ultralytics import settings  # pyright: ignore[reportMissingImports]
    except Exception as exc:  # ImportError, or torchvision failing to import inside it
        raise TerraError(
            f"{field}: the ultralytics runtime is not usable here ({type(exc).__name__}: {exc}); "
            f"{INSTALL_HINT}, or export the model to ONNX and use runtime yolo-onnx"
        ) from None
    settings.update({"sync": False})
    return ultralytics


class UltralyticsSegmentationModel:
    """A YOLO / FastSAM / YOLOE segmentation checkpoint run by ultralytics. With `prompts`, a YOLOE
    model's vocabulary is set to those texts (embedded by its own text encoder, or taken from a
    saved prompt-embedding file)."""

    def __init__(
        self,
        path: Path,
        device: Device,
        role: str,
        field: str,
        prompts: list[str] | None = None,
        prompt_embeddings: Path | None = None,
        text_encoder: Path | None = None,
        allow_download: bool = False,
    ):
        ultralytics = import_ultralytics(field, allow_download)
        self.path, self.device, self.field = Path(path), device, field
        self.files: list[ModelFile] = [weight_file(self.path, role)] if self.path.is_file() else []
        for extra, extra_role in ((prompt_embeddings, f"{role}-prompts"), (text_encoder, f"{role}-text-encoder")):
            if extra is not None:
                self.files.append(weight_file(extra, extra_role))
        try:
            self.model: _Model = (ultralytics.YOLOE if prompts else ultralytics.YOLO)(str(self.path))
            if prompts:
                self._set_prompts(prompts, prompt_embeddings, text_encoder)
        except TerraError:
            raise
        except Exception as exc:  # a foreign checkpoint, a non-YOLOE model given prompts, a missing text encoder
            raise TerraError(f"{field}: ultralytics cannot load {self.path} ({type(exc).__name__}: {exc})") from None
        names = self.model.names
        self.names = [str(names[k]) for k in sorted(names)] if isinstance(names, dict) else [str(n) for n in names]

    def _set_prompts(self, prompts: list[str], embeddings: Path | None, text_encoder: Path | None) -> None:
        if embeddings is not None:
            load_prompt_embeddings = getattr(self.model, "load_prompt_embeddings", None)
            if load_prompt_embeddings is None:
                raise TerraError(f"{self.field}: this ultralytics version cannot load prompt_embeddings; upgrade it")
            load_prompt_embeddings(str(embeddings))
            if list(self.model.names.values() if isinstance(self.model.names, dict) else self.model.names) != list(
                prompts
            ):
                raise TerraError(f"{self.field}: prompt_embeddings {embeddings} hold other prompts than {prompts}")
            return
        if text_encoder is not None:
            from ultralytics import settings  # pyright: ignore[reportMissingImports]

            settings.update({"weights_dir": str(Path(text_encoder).parent)})
        self.model.set_classes(list(prompts))

    def predict(self, image: np.ndarray, settings: DecodeSettings) -> Detections:
        """Detections with masks on the original image (ultralytics' own NMS and mask placement)."""
        image = np.asarray(image)
        results = self.model.predict(
            np.ascontiguousarray(image[..., 2::-1]),
            conf=settings.conf,
            iou=settings.iou,
            max_det=settings.max_det,
            agnostic_nms=settings.agnostic,
            retina_masks=True,
            verbose=False,
            device=self.device.torch if self.device.is_cuda else "cpu",
            half=self.device.fp16,
        )
        return _detections(results[0], image.shape[:2], settings)


def _detections(result: _Results, shape: tuple[int, int], settings: DecodeSettings) -> Detections:
    """Detections from one ultralytics Results object (masks thresholded at the configured probability)."""
    result_masks, result_boxes = result.masks, result.boxes
    if result_masks is None or result_boxes is None or len(result_boxes) == 0:
        return Detections(shape)
    masks = result_masks.data.cpu().numpy() > 0.5
    boxes = result_boxes.xyxy.cpu().numpy().astype(np.float64)
    scores = result_boxes.conf.cpu().numpy().astype(np.float32)
    classes = result_boxes.cls.cpu().numpy().round().astype(np.int64)
    keep, mask_boxes, crops = [], [], []
    for i, mask in enumerate(masks):
        rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
        if rows.size == 0 or int(np.count_nonzero(mask)) < settings.min_pixels:
            continue
        r0, r1, c0, c1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
        keep.append(i)
        mask_boxes.append((r0, c0, r1, c1))
        crops.append(mask[r0:r1, c0:c1].copy())
    order = np.asarray(keep, dtype=np.int64)
    return Detections(
        shape,
        boxes[order].reshape(-1, 4),
        scores[order],
        classes[order],
        np.asarray(mask_boxes, dtype=np.int64).reshape(-1, 4),
        crops,
    )
