"""The .npy arrays Terra reads (bundles, the reference folder layout): header first, then checks.

`read_npy` parses the header on its own and checks dtype and shape against what the caller expects
and the byte count against the file's size before anything is allocated, so a header claiming
10^12 rows is one line, not a 10 TiB allocation. Object, datetime, string and structured dtypes are
refused (no pickle, nothing the numeric code below cannot use). `ArraySpec` states what an array
must be (dtypes, shape, finiteness, a value range); `check_csr` checks the structure of a sparse
row-compressed matrix before SciPy or a compiled kernel trusts it. `smallest_unsigned` picks the
dtype counts are stored in.
"""

from __future__ import annotations

import os
import tokenize
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from terra.errors import TerraError
from terra.fileio import memory_error, open_regular, read_error

NUMERIC_KINDS = "biuf"  # bool, signed and unsigned integers, floats
MAX_HEADER = 10_000  # bytes of a header dict (numpy's own default limit)


@dataclass(frozen=True)
class ArraySpec:
    """What an array must be. dtypes: allowed dtype names ("float32", ...), empty for any numeric
    dtype; shape: one entry per axis, None for any length (None for the whole shape: any number of
    axes); finite: no NaN or infinity; low / high: inclusive bounds on every value; what: the
    array's meaning for messages ("x, y, z metres")."""

    dtypes: tuple[str, ...] = ()
    shape: tuple[int | None, ...] | None = None
    finite: bool = False
    low: float | None = None
    high: float | None = None
    what: str = ""

    def shape_text(self) -> str:
        if self.shape is None:
            return "any shape"
        return (
            "("
            + ", ".join("N" if s is None else str(s) for s in self.shape)
            + ("," if len(self.shape) == 1 else "")
            + ")"
        )

    def describe(self) -> str:
        dtype = " or ".join(self.dtypes) if self.dtypes else "numeric"
        return f"{dtype} {self.shape_text()}" + (f" ({self.what})" if self.what else "")


def _header(f, path: Path) -> tuple[tuple[int, ...], bool, np.dtype]:
    """(shape, fortran order, dtype) of an open .npy file, which is left at the start of the data."""
    fmt = np.lib.format
    try:
        version = fmt.read_magic(f)
        if version == (1, 0):
            shape, fortran, dtype = fmt.read_array_header_1_0(f, max_header_size=MAX_HEADER)
        elif version == (2, 0):
            shape, fortran, dtype = fmt.read_array_header_2_0(f, max_header_size=MAX_HEADER)
        else:
            raise ValueError(f"format version {version[0]}.{version[1]} is not read (1.0 and 2.0 are)")
    # What numpy's header parser raises on a damaged header: a short file, a broken literal
    # (ast and tokenize), a header dict with wrong keys or values, absurd nesting.
    except (ValueError, SyntaxError, EOFError, tokenize.TokenError, RecursionError, TypeError, MemoryError) as exc:
        reason = str(exc).strip().splitlines()[0][:120] if str(exc).strip() else type(exc).__name__
        raise TerraError(f"{path}: not a readable .npy array ({reason})") from None
    if not isinstance(shape, tuple) or not all(isinstance(n, int) and n >= 0 for n in shape):
        raise TerraError(f"{path}: .npy header has an invalid shape {shape!r}")
    return shape, bool(fortran), dtype


def _check_header(path: str | Path, shape: tuple[int, ...], dtype: np.dtype, spec: ArraySpec | None) -> None:
    if dtype.hasobject or dtype.kind not in NUMERIC_KINDS or dtype.fields is not None or dtype.subdtype is not None:
        raise TerraError(f"{path}: array of dtype {dtype}, expected numbers (no objects, dates, strings or records)")
    if spec is None:
        return
    if spec.dtypes and dtype.newbyteorder("=").name not in spec.dtypes:
        raise TerraError(f"{path}: array of dtype {dtype.name}, expected {spec.describe()}")
    if spec.shape is not None and (
        len(shape) != len(spec.shape) or any(s is not None and s != n for s, n in zip(spec.shape, shape))
    ):
        raise TerraError(f"{path}: array of shape {shape}, expected {spec.describe()}")


def read_npy(path: str | Path, spec: ArraySpec | None = None, mmap: bool = False, what: str = "array") -> np.ndarray:
    """The array in .npy file `path`, in native byte order, after `spec`'s checks; TerraError (one
    line naming the file) for anything else, including a byte count that does not match the header.
    `mmap`: map the data read-only instead of reading it."""
    path = Path(path)
    fd = open_regular(path, f".npy {what}")
    with os.fdopen(fd, "rb") as f:
        try:
            size = os.fstat(f.fileno()).st_size
            shape, fortran, dtype = _header(f, path)
            _check_header(path, shape, dtype, spec)
            offset = f.tell()
            count = int(np.prod(shape, dtype=object))
            nbytes = count * dtype.itemsize
            if size - offset != nbytes:
                raise TerraError(
                    f"{path}: header says {dtype.name} {shape} ({nbytes:,} bytes of data), "
                    f"the file holds {size - offset:,} (truncated or corrupt)"
                )
            if mmap and nbytes:
                array = np.memmap(
                    path, dtype=dtype, mode="r", offset=offset, shape=shape, order="F" if fortran else "C"
                )
            else:
                buffer = bytearray(nbytes)
                if f.readinto(buffer) != nbytes:
                    raise TerraError(f"{path}: shorter than its header says (truncated)")
                array = np.frombuffer(buffer, dtype=dtype).reshape(shape, order="F" if fortran else "C")
        except OSError as exc:
            raise read_error(path, exc, f".npy {what}") from None
        except MemoryError:
            raise memory_error(path, size, what) from None
    if not dtype.isnative:
        array = array.astype(dtype.newbyteorder("="))
    if spec is not None:
        check_values(array, spec, path)
    return array


def check_array(array: np.ndarray, spec: ArraySpec | None, where: str | Path) -> np.ndarray:
    """`array` (an array in memory, such as one a writer handed over in place of its file) after
    the checks `read_npy` makes of a file's header and values, naming `where`."""
    _check_header(where, tuple(array.shape), array.dtype, spec)
    if spec is not None:
        check_values(array, spec, where)
    return array


def check_values(array: np.ndarray, spec: ArraySpec, where: str | Path) -> None:
    """TerraError naming `where` unless the values meet `spec` (finite, within [low, high])."""
    if array.size == 0:
        return
    if spec.finite and array.dtype.kind == "f" and not np.isfinite(array).all():
        raise TerraError(f"{where}: holds NaN or infinite values, expected finite {spec.describe()}")
    if spec.low is not None or spec.high is not None:
        if array.dtype.kind == "f" and not spec.finite and not np.isfinite(array).all():
            raise TerraError(f"{where}: holds NaN or infinite values, expected {spec.describe()}")
        low, high = array.min(), array.max()
        if (spec.low is not None and low < spec.low) or (spec.high is not None and high > spec.high):
            bounds = (
                f"[{'-inf' if spec.low is None else _num(spec.low)}, {'inf' if spec.high is None else _num(spec.high)}]"
            )
            raise TerraError(f"{where}: values from {_num(low)} to {_num(high)}, expected {bounds} ({spec.describe()})")


def _num(value) -> str:
    value = float(value)
    return str(int(value)) if value.is_integer() and abs(value) < 2**63 else f"{value:g}"


def check_csr(indptr: np.ndarray, indices: np.ndarray, n_rows: int, n_cols: int, where: str) -> None:
    """TerraError naming `where` unless (indptr, indices) describe an (n_rows, n_cols) CSR matrix:
    indptr (n_rows + 1,) starts at 0, never decreases and ends at len(indices); every index lies in
    0..n_cols-1. SciPy's constructors and compiled kernels index memory by these without checks."""
    if indptr.ndim != 1 or indptr.shape[0] != n_rows + 1:
        raise TerraError(f"{where}: row pointer has shape {indptr.shape}, expected ({n_rows + 1},)")
    if indices.ndim != 1:
        raise TerraError(f"{where}: column indices have shape {indices.shape}, expected (nnz,)")
    if int(indptr[0]) != 0:
        raise TerraError(f"{where}: row pointer starts at {int(indptr[0])}, expected 0")
    if n_rows and np.any(np.diff(indptr) < 0):
        raise TerraError(f"{where}: row pointer decreases (corrupt sparse structure)")
    if int(indptr[-1]) != indices.shape[0]:
        raise TerraError(f"{where}: row pointer ends at {int(indptr[-1])}, but there are {indices.shape[0]} entries")
    if indices.size and (int(indices.min()) < 0 or int(indices.max()) >= n_cols):
        raise TerraError(
            f"{where}: column indices from {int(indices.min())} to {int(indices.max())}, expected 0..{n_cols - 1}"
        )


def write_npy(path: str | Path, array: np.ndarray) -> None:
    """Write `array` as a .npy file (no pickled objects). Encoded in memory and written in one call:
    `np.save` to a path goes through ndarray.tofile, whose short write on a full disk raises an
    OSError without errno or reason."""
    import io

    buf = io.BytesIO()
    np.save(buf, array, allow_pickle=False)  # the same bytes as np.save to a path
    Path(path).write_bytes(buf.getvalue())


def smallest_unsigned(values: np.ndarray) -> np.ndarray:
    """`values` (non-negative integers) in the smallest unsigned dtype that holds them."""
    top = int(values.max(initial=0))
    for dtype in (np.uint8, np.uint16, np.uint32):
        if top <= np.iinfo(dtype).max:
            return values.astype(dtype)
    return values.astype(np.uint64)
