"""Where models run: the configured device resolved against what this machine has.

`auto` means CUDA when torch sees a GPU, else the CPU. Asking for `cuda` on a machine without one is
a configuration error, not a silent fall-back: a user who asked for the GPU wants to know.
"""

from __future__ import annotations

from dataclasses import dataclass

from terra.errors import TerraError


@dataclass(frozen=True)
class Device:
    """A resolved device: `torch` is the torch device string (cpu, cuda:0), `fp16` whether models
    run in half precision there (only ever on a GPU)."""

    torch: str
    fp16: bool

    @property
    def is_cuda(self) -> bool:
        return self.torch.startswith("cuda")

    @property
    def index(self) -> int:
        return int(self.torch.partition(":")[2] or 0) if self.is_cuda else 0


def _cuda_count() -> int:
    try:
        import torch
    except ImportError:
        return 0
    return torch.cuda.device_count() if torch.cuda.is_available() else 0


def resolve_device(device: str = "auto", fp16: bool = True, field: str = "perception.models.device") -> Device:
    """The device for `device` (auto, cpu, cuda, cuda:N); half precision only where `fp16` and on a GPU."""
    if device == "cpu":
        return Device("cpu", False)
    count = _cuda_count()
    if device == "auto":
        return Device("cuda:0", bool(fp16)) if count else Device("cpu", False)
    index = int(device.partition(":")[2] or 0)
    if count == 0:
        raise TerraError(f"{field} is {device!r} but torch sees no CUDA GPU on this machine; use auto or cpu")
    if index >= count:
        raise TerraError(
            f"{field} is {device!r} but this machine has {count} CUDA device(s) (cuda:0..cuda:{count - 1})"
        )
    return Device(f"cuda:{index}", bool(fp16))


def onnx_providers(device: Device, field: str = "perception.models.device") -> list:
    """onnxruntime execution providers for `device` (CUDA first on a GPU, the CPU as fall-back for
    operators CUDA lacks)."""
    import onnxruntime as ort

    if not device.is_cuda:
        return ["CPUExecutionProvider"]
    if "CUDAExecutionProvider" not in ort.get_available_providers():
        raise TerraError(
            f"{field} resolves to {device.torch} but onnxruntime has no CUDAExecutionProvider "
            "(pip install onnxruntime-gpu instead of onnxruntime), or set it to cpu"
        )
    return [("CUDAExecutionProvider", {"device_id": device.index}), "CPUExecutionProvider"]
