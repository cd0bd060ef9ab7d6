"""Row patches of a live map chunk: the rows of an old chunk that changed since the chunk was
written, stored beside it, so a version rewrites what changed and not the 65,536 rows around it
(issue 25: a snapshot at most 200 ms at a million map points).

Per 100 frames of the campus drive about 20,000 older points are seen again, spread over three or
four chunks of 65,536 rows; rewriting those chunks whole was about 10 of the 17 MiB a version wrote
at a million points. A full chunk (every one but the growing last) whose changed rows since it was
written are at most `PATCH_SHARE` of its rows keeps its files, linked from the version before, and
gets a patch in the same folder (terra/mapping/chunks.py names the chunk's files):
  patch_rows (p,) int32: the changed rows, chunk-local, strictly ascending;
  patch_points, patch_votes, and on a voxel map patch_sums, patch_hits; with S > 1 sessions
  patch_session_hits (p, S) and patch_session_votes (S, p, T): those rows' values now, as the
  chunk's own arrays hold them (dtypes may be wider than the chunk's);
  patch_counts_indptr (p + 1,) int64, patch_counts_indices, patch_counts_data: those rows of the
  observation counts (CSR), replacing the chunk's rows whole.
A voxel's key never changes, so keys have no patch. A patch is cumulative: the next version's
patch of the chunk holds the rows of the one before and those changed since, with their values
now; once they exceed `PATCH_SHARE` of the rows the chunk is written whole again, without a patch.
Readers apply the patch when they read the chunk (`read_rows`), so nothing downstream sees it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from terra.errors import TerraError
from terra.npy import ArraySpec, check_csr

if TYPE_CHECKING:
    from terra.bundle import Bundle

# Above a quarter of the rows, the patch costs about what the chunk costs (each row is stored once
# more, in its own files) and every reader pays for applying it.
PATCH_SHARE = 0.25
PATCH_ROWS = "patch_rows"
_UNSIGNED = ("uint8", "uint16", "uint32", "uint64")


def patch_names(voxel: bool, sessions: bool) -> list[str]:
    """The array names of a chunk's patch, `patch_rows` first (module docstring)."""
    names = [PATCH_ROWS, "patch_points", "patch_votes"]
    names += ["patch_counts_indptr", "patch_counts_indices", "patch_counts_data"]
    names += ["patch_sums", "patch_hits"] if voxel else []
    names += ["patch_session_hits", "patch_session_votes"] if sessions else []
    return names


def stored_patch_rows(bundle: Bundle, folder: str, r: int) -> np.ndarray:
    """The chunk-local rows (p,) int64 patched in chunk `folder` of `r` rows (none without a patch):
    checked to be strictly ascending and inside the chunk (TerraError naming the file)."""
    if not bundle.has(f"{folder}/{PATCH_ROWS}"):
        return np.zeros(0, np.int64)
    rows = bundle.array(f"{folder}/{PATCH_ROWS}", ArraySpec(("int32",), (None,), low=0, high=r - 1, what="chunk rows"))
    if rows.size > 1 and np.any(np.diff(rows) <= 0):
        raise TerraError(f"{bundle.path}/{folder}/{PATCH_ROWS}.npy: rows must be strictly ascending")
    return rows.astype(np.int64)


def _patch_spec(name: str, p: int, t: int) -> ArraySpec:
    specs = {
        "points": ArraySpec(("float32",), (p, 3), finite=True, what="x, y, z metres, map frame"),
        "votes": ArraySpec(_UNSIGNED, (p, t), what="votes per point and terrain class"),
        "sums": ArraySpec(("float64",), (p, 3), finite=True, what="voxel coordinate sums, metres"),
        "hits": ArraySpec(_UNSIGNED, (p,), low=1, what="returns per voxel"),
        "session_hits": ArraySpec(_UNSIGNED, (p, None), what="returns per point and session"),
        "session_votes": ArraySpec(_UNSIGNED, (None, p, t), what="terrain votes per session"),
    }
    return specs[name]


def patched(bundle: Bundle, folder: str, name: str, base: np.ndarray, rows: np.ndarray, t: int) -> np.ndarray:
    """Array `name` of a chunk (`base`, as its own file holds it) with its patch applied at the
    chunk-local `rows` (stored_patch_rows); `base` itself when there is no patch."""
    if rows.size == 0:
        return base
    values = bundle.array(f"{folder}/patch_{name}", _patch_spec(name, rows.size, t))
    out = base.astype(np.result_type(base, values))  # a copy: the file's array stays as read
    if name == "session_votes":
        if values.shape[0] != base.shape[0]:
            raise TerraError(f"{bundle.path}/{folder}/patch_{name}.npy: expected {base.shape[0]} sessions")
        out[:, rows] = values
    else:
        if values.shape[1:] != base.shape[1:]:
            raise TerraError(f"{bundle.path}/{folder}/patch_{name}.npy: expected rows of shape {base.shape[1:]}")
        out[rows] = values
    return out


def patched_counts(
    bundle: Bundle, folder: str, counts: tuple[np.ndarray, np.ndarray, np.ndarray], rows: np.ndarray, k: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A chunk's observation counts (indptr, indices, data: CSR of r rows, K columns) with the rows
    of its patch replaced whole; the counts as given when there is no patch."""
    if rows.size == 0:
        return counts
    indptr, indices, data = counts
    r, p = indptr.size - 1, rows.size
    p_indptr = bundle.array(f"{folder}/patch_counts_indptr", ArraySpec(("int64",), (p + 1,), what="row pointer"))
    p_indices = bundle.array(f"{folder}/patch_counts_indices", ArraySpec(("int32",), (None,), what="bank ids"))
    p_data = bundle.array(
        f"{folder}/patch_counts_data", ArraySpec(_UNSIGNED, (p_indices.shape[0],), high=2**31 - 1, what="counts")
    )
    check_csr(p_indptr, p_indices, p, k, f"{bundle.path}/{folder}/patch_counts_*.npy")
    lengths = np.diff(indptr)
    from_patch = np.zeros(r, dtype=bool)
    from_patch[rows] = True
    lengths[rows] = np.diff(p_indptr)
    out_indptr = np.zeros(r + 1, dtype=np.int64)
    np.cumsum(lengths, out=out_indptr[1:])
    entry_patch = np.repeat(from_patch, lengths)
    entry_base = np.repeat(~from_patch, np.diff(indptr))
    out_indices = np.empty(int(out_indptr[-1]), dtype=np.int32)
    out_indices[entry_patch] = p_indices
    out_indices[~entry_patch] = indices[entry_base]
    out_data = np.empty(int(out_indptr[-1]), dtype=np.result_type(data, p_data))
    out_data[entry_patch] = p_data
    out_data[~entry_patch] = data[entry_base]
    return out_indptr, out_indices, out_data


def csr_rows(keys: np.ndarray, values: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows `rows` (p,) ascending of a sparse matrix kept as sorted entry keys (row << 32 | column)
    and their values: (indptr (p + 1,) int64, columns (nnz,) int32, values (nnz,))."""
    entry_rows = keys >> 32
    lo, hi = np.searchsorted(entry_rows, rows), np.searchsorted(entry_rows, rows + 1)
    lengths = hi - lo
    indptr = np.zeros(rows.size + 1, dtype=np.int64)
    np.cumsum(lengths, out=indptr[1:])
    at = np.repeat(lo - indptr[:-1], lengths) + np.arange(int(indptr[-1]))
    return indptr, (keys[at] & ((1 << 32) - 1)).astype(np.int32), values[at]
