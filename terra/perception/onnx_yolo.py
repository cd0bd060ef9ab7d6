"""The `yolo-onnx` runtime: any ultralytics segmentation export (.onnx) run with onnxruntime.

`yolo export format=onnx` writes one input `images` (1, 3, H, W) float in 0..1, RGB, and two outputs,
`output0` (boxes, class scores, mask coefficients) and `output1` (mask prototypes), described in
terra/perception/yolo.py. Its metadata (`custom_metadata_map` in onnxruntime, `metadata_props` in
onnx) holds Python-literal strings: `names` ({0: 'sidewalk', ...}), `imgsz` ([640, 640]), `stride`,
`task` ('segment'). Fine-tuned terrain YOLO, FastSAM (one class) and YOLOE exports with a fixed
vocabulary all share this signature.
"""

from __future__ import annotations

import ast
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from terra.errors import TerraError
from terra.perception.device import Device, onnx_providers
from terra.perception.letterbox import Letterbox
from terra.perception.weights import ModelFile, weight_file
from terra.perception.yolo import DecodeSettings, Detections, decode, output_layout

if TYPE_CHECKING:
    import onnx
    import onnxruntime

DEFAULT_IMGSZ = (640, 640)


def _literal(value: str) -> object:
    try:
        return ast.literal_eval(value)
    except (ValueError, SyntaxError):
        return None


def parse_names(value: object) -> list[str] | None:
    """Class names in index order from the `names` metadata ({0: 'a', 1: 'b'} or ['a', 'b'])."""
    if isinstance(value, str):
        value = _literal(value)
    if isinstance(value, dict) and value:
        try:
            keys = sorted(int(k) for k in value)
        except (TypeError, ValueError):
            return None
        if keys != list(range(len(keys))):
            return None
        return [str(value.get(k, value.get(str(k)))) for k in keys]
    if isinstance(value, (list, tuple)) and value:
        return [str(v) for v in value]
    return None


class OnnxSegmentationModel:
    """One ultralytics segmentation export. `names`: class names (metadata, else configured, else
    None); `input_shape`: (H, W) the images are letterboxed to; `files`: the weight file's identity.
    The onnxruntime session is created on first use."""

    def __init__(
        self,
        path: Path,
        device: Device,
        role: str,
        field: str,
        names: list[str] | None = None,
        imgsz: list[int] | None = None,
    ):
        import onnx

        self.path = Path(path)
        self.device = device
        self.field = field
        try:
            proto = onnx.load(str(self.path), load_external_data=False)
        except Exception as exc:  # a truncated or foreign file: protobuf raises its own errors
            raise TerraError(
                f"{field}: {self.path} is not a readable ONNX model ({type(exc).__name__}: {exc})"
            ) from None
        meta = {p.key: p.value for p in proto.metadata_props}
        self.metadata = meta
        self.names = list(names) if names else parse_names(meta.get("names"))
        inputs = [i for i in proto.graph.input if i.name not in {t.name for t in proto.graph.initializer}]
        outputs = [o.name for o in proto.graph.output]
        if len(inputs) != 1 or len(outputs) < 2:
            raise TerraError(
                f"{field}: {self.path} has {len(inputs)} input(s) and {len(outputs)} output(s); an "
                "ultralytics segmentation export has one input (images) and two outputs (output0, output1)"
            )
        self.input_name = inputs[0].name
        self.output_names = outputs[:2]
        dims = _dims(inputs[0])
        self.input_shape = self._input_shape(dims, meta, imgsz)
        self.half = inputs[0].type.tensor_type.elem_type == onnx.TensorProto.FLOAT16
        self._check_names([_dims(o) for o in proto.graph.output[:2]])
        self.files: list[ModelFile] = [weight_file(self.path, role)]
        self._session: onnxruntime.InferenceSession | None = None

    def _check_names(self, shapes: list[list[int | None]]) -> None:
        """Names that do not fit a static output0 are refused now rather than at the first image."""
        out0, out1 = shapes
        static0 = tuple(d for d in out0 if d is not None)
        if not self.names or len(out0) != 3 or len(out1) != 4 or len(static0) != 3 or out1[1] is None:
            return
        try:
            output_layout(static0, len(self.names), int(out1[1]))
        except ValueError as exc:
            raise TerraError(f"{self.field}: {self.path}: {exc}; its names ({len(self.names)}) do not fit") from None

    def _input_shape(self, dims: list[int | None], meta: dict[str, str], imgsz: list[int] | None) -> tuple[int, int]:
        if len(dims) != 4 or (dims[1] not in (None, 3)):
            raise TerraError(
                f"{self.field}: {self.path} takes input of shape {dims}; expected (1, 3, height, width) images"
            )
        if dims[2] and dims[3]:
            return int(dims[2]), int(dims[3])
        if imgsz:
            return int(imgsz[0]), int(imgsz[1])
        size = _literal(meta.get("imgsz", ""))
        if isinstance(size, (list, tuple)) and len(size) == 2:
            return int(size[0]), int(size[1])
        if isinstance(size, int):
            return size, size
        return DEFAULT_IMGSZ

    @property
    def session(self) -> onnxruntime.InferenceSession:
        if self._session is None:
            import onnxruntime as ort

            options = ort.SessionOptions()
            options.log_severity_level = 3  # errors only: the library never prints
            try:
                self._session = ort.InferenceSession(
                    str(self.path), sess_options=options, providers=onnx_providers(self.device, self.field)
                )
            except TerraError:
                raise
            except Exception as exc:  # onnxruntime reports graph faults as its own exception types
                raise TerraError(
                    f"{self.field}: onnxruntime cannot load {self.path} ({type(exc).__name__}: {exc})"
                ) from None
        return self._session

    def run(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray, Letterbox]:
        """Raw outputs (output0, protos) and the letterbox of one (H, W, 3) uint8 RGB image."""
        box = Letterbox.fit(np.shape(image)[:2], self.input_shape)
        tensor = box.apply(image)
        if self.half:
            tensor = tensor.astype(np.float16)
        output0, protos = self.session.run(self.output_names, {self.input_name: tensor})
        return np.asarray(output0, np.float32), np.asarray(protos, np.float32), box

    def predict(self, image: np.ndarray, settings: DecodeSettings) -> Detections:
        """Detections with masks on the original image."""
        output0, protos, box = self.run(image)
        nm = protos.shape[1]
        nc = len(self.names) if self.names else _classes_from_shape(output0.shape, nm)
        try:
            return decode(output0, protos, nc, box, settings)
        except ValueError as exc:
            raise TerraError(f"{self.field}: {self.path}: {exc} (are the configured names right?)") from None


def _dims(value_info: onnx.ValueInfoProto) -> list[int | None]:
    """Static dimensions of a graph input or output (None where symbolic)."""
    return [d.dim_value if d.HasField("dim_value") else None for d in value_info.type.tensor_type.shape.dim]


def _classes_from_shape(shape: tuple[int, ...], nm: int) -> int:
    """Number of classes of a raw output0 (1, 4 + nc + nm, anchors) when no names are known."""
    if len(shape) == 3 and shape[2] == 6 + nm:
        return 1  # end-to-end layout: the class count does not appear in the shape
    return int(shape[1]) - 4 - nm
