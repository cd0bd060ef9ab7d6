"""The authors' metric-semantic map files (reference-notes.md section 1, "MS-map outputs"):
their names, and reading them without running anything they might contain.

In an output folder, each save N (`_itr{N}`, the index of the last scan processed) is a full
snapshot:
  gidx2clipcounts_dict_itr{N}.pkl      {global_idx: {clip_id: count}}
  clip_segs_itr{N}.pt                  (K, D) embedding bank; rows 0..C-1 embed the C class names
  clip_imgs_itr{N}.pt                  (M, D) whole-image embeddings, L2-normalised
  saved_img_names_itr{N}.pkl           ["camera{n}_images/cam{n}_img_{t:.6f}.jpg", ...] (n from 1)
  gidx2imgs_{thr}m_dict_itr{N}.pkl     {global_idx: set(img_idx)} images within thr metres
  gidx2closestimg_dict_itr{N}.pkl      {global_idx: {img_idx}} the closest image
  gidx2closestimgdist_dict_itr{N}.pkl  {global_idx: range_m}
and the dataset's global map global_pc/global_pc_{t:.6f}.npy (N, 4) x, y, z, intensity.

Their pickles are read by `load_pickle`, an unpickler that builds only plain containers (dict,
list, tuple, set), numbers, strings, bytes, numpy arrays and scalars, and torch tensors (whose
storages it loads with torch's weights-only loader); any other type is refused, naming the file
and the type, before it is built. Torch files go through `torch.load(weights_only=True,
map_location="cpu")`, so tensors saved on a GPU load on a machine without one.
"""

from __future__ import annotations

import io
import os
import pickle
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from terra.errors import TerraError

COUNTS = "gidx2clipcounts_dict_itr{n}.pkl"
BANK = "clip_segs_itr{n}.pt"
IMAGE_EMBEDDINGS = "clip_imgs_itr{n}.pt"
IMAGE_NAMES = "saved_img_names_itr{n}.pkl"
IMAGES_WITHIN = "gidx2imgs_{thr}m_dict_itr{n}.pkl"
CLOSEST_IMAGE = "gidx2closestimg_dict_itr{n}.pkl"
CLOSEST_DISTANCE = "gidx2closestimgdist_dict_itr{n}.pkl"
GLOBAL_PC = "global_pc/global_pc_{t}.npy"
SIDECAR = "terra_reference.json"  # written by Terra's export; the authors' scripts ignore it
VISIBILITY = "terra_visibility.npy"  # Terra's export: (n, 2) int64 (visibility cell key, image) pairs
REFERENCE_DIM = 512  # their Phase 2 sums embeddings into torch.zeros(512) (CLIP ViT-B/16's width)
MAX_INDEX = 2**62  # the largest index or count taken from their pickles (int64 arithmetic stays exact)

IMAGE_NAME = re.compile(r"camera(\d+)_images[/\\]cam(\d+)_img_(-?\d+(?:\.\d+)?)\.jpg$")


def image_name(camera: int, stamp: float) -> str:
    """The reference's name of camera `camera`'s (0-based) image at `stamp` seconds (cameras
    are numbered from 1 and stamps written with 6 decimals in their files)."""
    n = int(camera) + 1
    return f"camera{n}_images/cam{n}_img_{stamp:.6f}.jpg"


def stamp_text(stamp: float) -> str:
    return f"{stamp:.6f}"


def range_text(metres: float) -> str:
    """How the reference writes its image range in file names: the YAML float, e.g. 20.0."""
    return repr(float(metres))


def range_from_name(path: Path, text: str) -> float:
    """The image range (metres) of a gidx2imgs_{thr}m_dict file from its `thr` text (TerraError
    naming the file unless it is a positive finite number)."""
    try:
        metres = float(text)
    except ValueError:
        metres = float("nan")
    if not np.isfinite(metres) or metres <= 0:
        raise TerraError(
            f"{path}: the image range in the name must be a positive number of metres "
            f"(gidx2imgs_{{thr}}m_dict with their YAML float, e.g. 20.0), found {short(text)!r}"
        )
    return metres


def short(text: str, limit: int = 40) -> str:
    """`text` cut to `limit` characters for a message (a file may hold anything)."""
    text = " ".join(text.split())  # one line (a numpy array's repr spans several)
    return text if len(text) <= limit else text[:limit] + "..."


def unit_rows(vectors: np.ndarray, tolerance: float = 1e-6) -> np.ndarray:
    """float32 rows scaled to unit length where their norm is off by more than `tolerance`; rows
    already unit are kept bit for bit (normalising them again can move the last bit, and an export
    and import would then not give back the same vectors)."""
    vectors = np.array(vectors, dtype=np.float32)
    wide = vectors.astype(np.float64)  # float32 norms overflow past 1e19 per element
    norms = np.linalg.norm(wide, axis=-1, keepdims=True)
    off = np.abs(norms[:, 0] - 1.0) > tolerance
    scaled = np.divide(wide[off], norms[off], out=np.zeros_like(wide[off]), where=norms[off] > 0)
    vectors[off] = scaled.astype(np.float32)
    return vectors


def padded(vectors: np.ndarray, width: int) -> np.ndarray:
    """(n, max(d, width)) float32: the (n, d) rows with zero columns appended (norms and cosines
    unchanged), so their Phase 2's 512-wide sums accept vectors of a narrower embedder."""
    vectors = np.asarray(vectors, dtype=np.float32)
    out = np.zeros((vectors.shape[0], max(vectors.shape[1], width)), dtype=np.float32)
    out[:, : vectors.shape[1]] = vectors
    return out


# ------------------------------------------------------------------------------ safe pickles


def _latin1_encode(text: str, encoding: str = "utf-8") -> bytes:
    """`_codecs.encode` as protocol-2 pickles use it for bytes (latin-1 only)."""
    if encoding not in ("latin1", "latin-1"):
        raise pickle.UnpicklingError(f"_codecs.encode with encoding {encoding!r}")
    return str(text).encode("latin1")


def _tensor_from_bytes(data: bytes) -> Any:
    """What `torch.storage._load_from_bytes` does, through torch's weights-only loader on the CPU."""
    import torch

    return torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)


def _allowed_globals() -> dict[tuple[str, str], Callable[[], Any]]:
    """(module, name) -> a function returning the object to use for it."""
    allowed: dict[tuple[str, str], Callable[[], Any]] = {
        ("builtins", "set"): lambda: set,
        ("builtins", "frozenset"): lambda: frozenset,
        ("builtins", "complex"): lambda: complex,
        ("builtins", "bytearray"): lambda: bytearray,
        ("collections", "OrderedDict"): lambda: __import__("collections").OrderedDict,
        ("_codecs", "encode"): lambda: _latin1_encode,
        ("numpy", "ndarray"): lambda: np.ndarray,
        ("numpy", "dtype"): lambda: np.dtype,
        ("torch._utils", "_rebuild_tensor_v2"): _rebuild_tensor,
        ("torch.storage", "_load_from_bytes"): lambda: _tensor_from_bytes,
    }
    for module in ("numpy.core.multiarray", "numpy._core.multiarray"):  # numpy 1 and 2 pickles
        allowed[(module, "_reconstruct")] = lambda: _multiarray()._reconstruct
        allowed[(module, "scalar")] = lambda: _multiarray().scalar
    for module in ("numpy.core.numeric", "numpy._core.numeric"):  # protocol 5 arrays
        allowed[(module, "_frombuffer")] = _frombuffer
    return allowed


def _frombuffer() -> Any:
    # numpy's own unpickling helper for protocol 5 arrays: private, so its stubs do not list it.
    try:
        from numpy._core.numeric import _frombuffer  # pyright: ignore[reportAttributeAccessIssue]
    except ImportError:  # numpy < 2
        from numpy.core.numeric import _frombuffer  # pyright: ignore[reportAttributeAccessIssue]
    return _frombuffer


def _multiarray() -> Any:
    try:
        from numpy._core import multiarray
    except ImportError:  # numpy < 2
        from numpy.core import multiarray
    return multiarray


def _rebuild_tensor() -> Any:
    from torch._utils import _rebuild_tensor_v2

    return _rebuild_tensor_v2


class PlainDataUnpickler(pickle.Unpickler):
    """Builds only the types of `_allowed_globals`; TerraError naming the file for anything else."""

    def __init__(self, file, path: Path):
        super().__init__(file)
        self._path = path
        self._allowed = _allowed_globals()

    def find_class(self, module: str, name: str) -> Any:
        module = "builtins" if module == "__builtin__" else module  # protocol-2 pickles name Python 2's module
        factory = self._allowed.get((module, name))
        if factory is None:
            raise TerraError(
                f"{self._path}: holds an object of type {module}.{name}; only plain data (dict, list, tuple, set, "
                "numbers, strings, numpy or torch arrays) is read from the reference's files"
            )
        return factory()

    def persistent_load(self, pid: Any) -> Any:
        raise TerraError(f"{self._path}: holds a persistent reference ({type(pid).__name__}); plain pickles have none")


def load_pickle(path: Path) -> Any:
    """The plain data in pickle file `path` (see the module docstring)."""
    from terra.fileio import open_regular

    path = Path(path)
    try:
        with os.fdopen(open_regular(path, "pickle file"), "rb") as f:
            return PlainDataUnpickler(f, path).load()
    except TerraError:
        raise
    except FileNotFoundError:
        raise TerraError(f"{path}: file not found") from None
    except (RecursionError, MemoryError) as exc:
        raise TerraError(
            f"{path}: not a readable pickle of plain data ({type(exc).__name__}: nested or sized "
            "beyond what plain map data needs)"
        ) from None
    except (
        pickle.UnpicklingError,
        EOFError,
        ValueError,
        TypeError,
        AttributeError,
        IndexError,
        KeyError,
        UnicodeDecodeError,
        OSError,
        RuntimeError,
    ) as exc:
        raise TerraError(f"{path}: not a readable pickle of plain data ({type(exc).__name__}: {exc})") from None


def load_tensor(path: Path) -> np.ndarray:
    """The tensor in torch file `path` as a float32 array, loaded on the CPU with weights only."""
    import torch

    path = Path(path)
    if not path.is_file():
        raise TerraError(f"{path}: file not found")
    try:
        obj = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        raise TerraError(
            f"{path}: holds {_unsafe_globals(path, exc)}; only tensors are read from the reference's torch files"
        ) from None
    # torch's weights-only unpickler meets garbled opcodes with whatever its stack does (IndexError...)
    except (
        RuntimeError,
        EOFError,
        OSError,
        ValueError,
        KeyError,
        AttributeError,
        IndexError,
        TypeError,
        UnicodeDecodeError,
        MemoryError,
        RecursionError,
    ) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise TerraError(f"{path}: unreadable torch file ({first})") from None
    if not isinstance(obj, torch.Tensor):
        raise TerraError(f"{path}: holds a {type(obj).__module__}.{type(obj).__qualname__}, expected one tensor")
    if not (
        obj.dtype.is_floating_point or obj.dtype in (torch.int8, torch.int16, torch.int32, torch.int64, torch.uint8)
    ):
        raise TerraError(f"{path}: tensor of dtype {obj.dtype}, expected a real-valued tensor")
    array = obj.detach().to(torch.float64).numpy()
    if not np.isfinite(array).all():
        raise TerraError(f"{path}: holds NaN or infinite values, expected finite embeddings")
    if np.abs(array).max(initial=0.0) > np.finfo(np.float32).max:
        raise TerraError(f"{path}: holds values beyond float32's range, expected embeddings")
    return array.astype(np.float32)


def _unsafe_globals(path: Path, exc: Exception) -> str:
    """The types a refused torch file names (from torch's own scan where it can tell)."""
    try:
        from torch.serialization import get_unsafe_globals_in_checkpoint

        found = get_unsafe_globals_in_checkpoint(path)
        if found:
            return "an object of type " + ", ".join(sorted(found))
    except Exception:  # noqa: BLE001 - the scan only improves the message; the refusal stands
        pass
    match = re.search(r"GLOBAL ([\w.]+)", str(exc))
    return f"an object of type {match.group(1)}" if match else "data other than tensors"


# ------------------------------------------------------------------------------ shapes


def shown(value: Any) -> str:
    """`value` for a message: integers past 64 bits by their size (the digits of a huge one are
    neither readable nor cheap), anything else by a repr cut to 40 characters."""
    if isinstance(value, int) and not isinstance(value, bool) and value.bit_length() > 63:
        bits = value.bit_length()
        return f"{value} (a {bits}-bit integer)" if bits <= 128 else f"a {bits}-bit integer"
    return short(repr(value))


def as_index(value: Any, path: Path, what: str) -> int:
    """A non-negative integer up to MAX_INDEX from an int or numpy integer (TerraError otherwise)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)) or not 0 <= value <= MAX_INDEX:
        raise TerraError(
            f"{path}: {what} must be integers from 0 to 2**62, found {shown(value)} ({type(value).__name__})"
        )
    return int(value)


def as_range(value: Any, path: Path, key: int) -> float:
    """A finite range in metres >= 0 from an int or float of any kind (TerraError otherwise)."""
    number: float | None = None
    if not isinstance(value, (bool, np.bool_)) and isinstance(value, (int, float, np.integer, np.floating)):
        try:
            number = float(value)
        except OverflowError:  # an int beyond float's range
            number = None
    if number is None or not np.isfinite(number) or number < 0:
        raise TerraError(f"{path}: entry {key}: expected a finite range in metres >= 0, got {shown(value)}")
    return number


def as_dict(obj: Any, path: Path, shape: str) -> dict:
    if not isinstance(obj, dict):
        raise TerraError(f"{path}: expected a dict {shape}, found a {type(obj).__name__}")
    return obj


def as_index_set(value: Any, path: Path, what: str) -> list[int]:
    """Image indices from a set, list, tuple or integer array."""
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if not isinstance(value, (set, frozenset, list, tuple)):
        raise TerraError(f"{path}: {what} must be sets of image indices, found a {type(value).__name__}")
    return sorted(as_index(v, path, what) for v in value)
