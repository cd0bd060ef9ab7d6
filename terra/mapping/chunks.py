"""Row chunks: how a live map version stores its per-point arrays, so that the next version shares
with it every chunk in which no point changed (issue 25: a snapshot costs what changed, not the map).

The flat layout (terra/mapping/storage.py, terra/mapping/state.py) stores every per-point array in
voxel-key order; one new voxel shifts every row after it, so each version
wrote the whole map again. A chunked version (components.map.chunk_rows = R) keeps them instead
in creation order (the order in which the fusion first saw each point: new points are appended),
cut into chunks of R rows; chunk c holds rows [c R, (c + 1) R), under `map/chunks/<c, 5 digits>/`:
  keys (r,) int64 voxel keys, sums (r, 3) float64 metres, hits (r,) smallest unsigned type:
  the voxel accumulators (voxel maps only; a fixed map's point order is its own);
  points (r, 3) float32 metres, map frame (sums / hits on a voxel map);
  votes (r, T) smallest unsigned type: terrain votes, exact (the read view caps them at 65,535);
  counts_indptr (r + 1,) int64, counts_indices (nnz_c,) int32, counts_data (nnz_c,) smallest
  unsigned type: the chunk's rows of the sparse (N, K) observation counts;
  session_hits (r, S), session_votes (S, r, T), smallest unsigned type: only with S > 1 sessions.
The rest of `map/` (bank, terrain embeddings, images, visibility, meta.json, state/bank,
state/meta.json) is stored as in the flat layout, and the flat per-point files are absent.

A version rewrites the chunks holding a row the fusion touched since the version before
(`MapFusion.touched`: every change of a row comes from a scan point associated to it; a new
session touches every row) and the last, growing one, and hard-links the others from the version
it starts from (BundleWriter.keep_from_base). A full chunk in which few rows changed since it was
written keeps its files too and gets a row patch beside them (terra/mapping/chunk_patches.py),
which readers apply. Each file is verified by its SHA-256 as any bundle file.
Readers see the rows in creation order (terra/mapping/chunk_views.py), the flat layout's arrays in
another row order; MS-Avg norms and MS-Max ids are computed when first asked.
Live sessions write chunked versions; batch runs (`terra map`, `--append`) and a session's closing
version write the flat layout, which every reader of finished bundles expects.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
import scipy.sparse as sp

from terra.errors import TerraError
from terra.mapping.association import VoxelMap, grown
from terra.mapping.chunk_patches import (
    PATCH_ROWS,
    PATCH_SHARE,
    csr_rows,
    patch_names,
    patched,
    patched_counts,
    stored_patch_rows,
)
from terra.mapping.fusion import MapFusion
from terra.npy import ArraySpec, check_csr, smallest_unsigned

if TYPE_CHECKING:
    from terra.bundle import Bundle, BundleWriter

CHUNK_ROWS = 1 << 16  # 65,536 points: about 4 MB a chunk; a campus snapshot rewrites a third of them
_UNSIGNED = ("uint8", "uint16", "uint32", "uint64")
_U16_MAX = int(np.iinfo(np.uint16).max)
_ENTRY_MASK = (1 << 32) - 1


# The files of a chunk the read view is made of (terra/mapping/chunk_views.py), those of its row patch
# included: handed over to the view of the process that writes them (BundleWriter.put_array).
VIEW_FILES = ("points", "votes", "counts_indptr", "counts_indices", "counts_data")
PATCH_VIEW_FILES = tuple(f"patch_{name}" for name in VIEW_FILES) + (PATCH_ROWS,)


def chunk_folder(c: int) -> str:
    return f"map/chunks/{c:05d}"


def chunk_files(c: int, voxel: bool, sessions: bool) -> list[str]:
    """The file names of chunk `c` (module docstring)."""
    names = ["points", "votes", "counts_indptr", "counts_indices", "counts_data"]
    names += ["keys", "sums", "hits"] if voxel else []
    names += ["session_hits", "session_votes"] if sessions else []
    return [f"{chunk_folder(c)}/{name}.npy" for name in names]


def chunk_count(n: int, rows: int) -> int:
    return (n + rows - 1) // rows


def write_chunks(writer: BundleWriter, fusion: MapFusion, base: Bundle | None, rows: int = CHUNK_ROWS) -> int:
    """Put the per-point arrays of `fusion` into the version being written as chunks of `rows`
    rows, carrying unchanged chunks over from `base` (the version the writer starts from, whose
    chunks hold the fusion's rows as they were when it was committed) and patching full chunks in
    which few rows changed (terra/mapping/chunk_patches.py). Returns the chunks written whole."""
    n = fusion.geometry.size
    count = chunk_count(n, rows)
    touched = fusion.touched_rows()
    changed = np.zeros(count, dtype=bool)
    changed[touched // rows] = True
    info = base.model.components.map if base is not None else None
    shareable = info is not None and info.chunk_rows == rows
    full_in_base = int(info.points or 0) // rows if shareable and info is not None else 0
    voxel, sessions = isinstance(fusion.geometry, VoxelMap), fusion.session_hits.shape[1] > 1
    fusion.counts.compact()
    count_rows = fusion.counts.keys >> 32
    written = 0
    for c in range(count):
        files = chunk_files(c, voxel, sessions)
        if shareable and base is not None and c < full_in_base:
            patch = [f"{chunk_folder(c)}/{name}.npy" for name in patch_names(voxel, sessions)]
            if not changed[c] and writer.keep_from_base(files + (patch if base.has(patch[0][:-4]) else [])):
                continue
            local = touched[(touched >= c * rows) & (touched < (c + 1) * rows)] - c * rows
            if changed[c] and _patch_chunk(writer, fusion, base, c, rows, local, files):
                continue
        _put_chunk(writer, fusion, c, c * rows, min(n, (c + 1) * rows), count_rows)
        written += 1
    return written


def _patch_chunk(
    writer: BundleWriter, fusion: MapFusion, base: Bundle, c: int, rows: int, local: np.ndarray, files: list[str]
) -> bool:
    """Chunk `c` (full, `rows` rows) as the base's files and a patch of its rows changed since they
    were written: those of the base's patch and `local` (chunk-local, ascending); False (nothing
    written) when they are over PATCH_SHARE of the rows or the base lacks a file of the chunk."""
    folder = chunk_folder(c)
    try:
        before = stored_patch_rows(base, folder, rows)
    except TerraError:
        return False  # a damaged patch: the chunk is written whole again
    patch = np.union1d(before, local)
    if patch.size > PATCH_SHARE * rows or not writer.keep_from_base(files):
        return False

    def put(name: str, array: np.ndarray) -> None:
        writer.put_array(f"{folder}/{name}", array, share=True, hand_over=name in PATCH_VIEW_FILES)

    put(PATCH_ROWS, patch.astype(np.int32))
    at = c * rows + patch  # the rows in creation order
    if isinstance(fusion.geometry, VoxelMap):
        voxels = fusion.geometry.state(at)
        put("patch_sums", voxels["sums"])
        put("patch_hits", smallest_unsigned(voxels["hits"]))
        put("patch_points", (voxels["sums"] / voxels["hits"][:, None]).astype(np.float32))  # as _put_chunk
    else:
        put("patch_points", fusion.geometry.points()[at])
    n = fusion.geometry.size
    put("patch_votes", smallest_unsigned(grown(fusion.votes, n)[at]))
    indptr, columns, values = csr_rows(fusion.counts.keys, fusion.counts.values, at)
    put("patch_counts_indptr", indptr)
    put("patch_counts_indices", columns)
    put("patch_counts_data", smallest_unsigned(values))
    if fusion.session_hits.shape[1] > 1:
        put("patch_session_hits", smallest_unsigned(grown(fusion.session_hits, n)[at]))
        put("patch_session_votes", smallest_unsigned(fusion.row_session_votes(c * rows, (c + 1) * rows)[:, patch]))
    return True


def _put_chunk(writer: BundleWriter, fusion: MapFusion, c: int, start: int, stop: int, count_rows: np.ndarray) -> None:
    """Chunk `c`: rows [start, stop) of the fusion state (module docstring)."""
    folder, geometry, n = chunk_folder(c), fusion.geometry, fusion.geometry.size

    def put(name: str, array: np.ndarray) -> None:  # an array that did not change keeps its file
        writer.put_array(name, array, share=True, hand_over=name.rsplit("/", 1)[-1] in VIEW_FILES)

    if isinstance(geometry, VoxelMap):
        voxels = geometry.state(slice(start, stop))  # views: written from the fusion's own memory
        put(f"{folder}/keys", voxels["keys"])
        put(f"{folder}/sums", voxels["sums"])
        put(f"{folder}/hits", smallest_unsigned(voxels["hits"]))
        points = (voxels["sums"] / voxels["hits"][:, None]).astype(np.float32)  # as VoxelMap.points()
    else:
        points = geometry.points()[start:stop]
    put(f"{folder}/points", points)
    put(f"{folder}/votes", smallest_unsigned(grown(fusion.votes, n)[start:stop]))
    lo, hi = np.searchsorted(count_rows, [start, stop])
    local = count_rows[lo:hi] - start
    indptr = np.concatenate([[0], np.cumsum(np.bincount(local, minlength=stop - start))]).astype(np.int64)
    put(f"{folder}/counts_indptr", indptr)
    put(f"{folder}/counts_indices", (fusion.counts.keys[lo:hi] & _ENTRY_MASK).astype(np.int32))
    put(f"{folder}/counts_data", smallest_unsigned(fusion.counts.values[lo:hi]))
    if fusion.session_hits.shape[1] > 1:
        put(f"{folder}/session_hits", smallest_unsigned(grown(fusion.session_hits, n)[start:stop]))
        put(f"{folder}/session_votes", smallest_unsigned(fusion.row_session_votes(start, stop)))


def is_chunked(bundle: Bundle) -> bool:
    info = bundle.model.components.map
    return info is not None and info.chunk_rows is not None


def stored_chunk_rows(bundle: Bundle) -> int:
    """components.map.chunk_rows of a chunked map (TerraError when it is below 1)."""
    info = bundle.model.components.map
    rows = int(info.chunk_rows or 0) if info is not None else 0
    if rows < 1:
        raise TerraError(f"{bundle.path}/manifest.json: field 'components.map.chunk_rows' must be at least 1")
    return rows


def read_rows(
    bundle: Bundle, names: tuple[str, ...], n: int, k: int, t: int, chunks: Sequence[int] | None = None
) -> dict[str, np.ndarray]:
    """The arrays `names` of a chunked map (e.g. "points", "votes", "counts", "keys") over its `n`
    rows in creation order, each chunk checked against its size and SHA-256 and its shape and
    dtype, with each chunk's row patch applied (terra/mapping/chunk_patches.py); "counts" gives
    counts_indptr, counts_indices, counts_data of the whole (n, k) matrix.
    chunks: only these chunks (ascending), their rows one after the other (default: all)."""
    rows = stored_chunk_rows(bundle)
    parts: dict[str, list[np.ndarray]] = {name: [] for name in names if name != "counts"}
    indptr, indices, data = [np.zeros(1, np.int64)], [np.zeros(0, np.int32)], [np.zeros(0, np.uint8)]
    for c in range(chunk_count(n, rows)) if chunks is None else chunks:
        r, folder = min(rows, n - c * rows), chunk_folder(c)
        patch = stored_patch_rows(bundle, folder, r)  # rows changed since the chunk was written
        for name in parts:
            array = bundle.array(f"{folder}/{name}", _spec(name, r, t))
            parts[name].append(array if name == "keys" else patched(bundle, folder, name, array, patch, t))
        if "counts" in names:
            p, i, d = patched_counts(bundle, folder, _chunk_counts(bundle, c, r, k), patch, k)
            indptr.append(p[1:] + indptr[-1][-1])
            indices.append(i)
            data.append(d)
    out = {name: np.concatenate(arrays) if arrays else _empty(name, t) for name, arrays in parts.items()}
    if "session_votes" in out and parts["session_votes"]:
        out["session_votes"] = np.concatenate(parts["session_votes"], axis=1)
    if "counts" in names:
        out.update(counts_indptr=np.concatenate(indptr), counts_indices=np.concatenate(indices))
        out["counts_data"] = np.concatenate([d.astype(np.int64) for d in data])
    return out


def _chunk_counts(bundle: Bundle, c: int, r: int, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    folder = chunk_folder(c)
    indptr = bundle.array(f"{folder}/counts_indptr", ArraySpec(("int64",), (r + 1,), what="chunk row pointer"))
    indices = bundle.array(f"{folder}/counts_indices", ArraySpec(("int32",), (None,), what="bank ids"))
    data = bundle.array(
        f"{folder}/counts_data", ArraySpec(_UNSIGNED, (indices.shape[0],), low=0, high=2**31 - 1, what="counts")
    )
    check_csr(indptr, indices, r, k, f"{bundle.path}/{folder}/counts_*.npy")
    return indptr, indices, data


def _spec(name: str, r: int, t: int) -> ArraySpec:
    specs = {
        "keys": ArraySpec(("int64",), (r,), what="voxel keys"),
        "sums": ArraySpec(("float64",), (r, 3), finite=True, what="voxel coordinate sums, metres"),
        "hits": ArraySpec(_UNSIGNED, (r,), low=1, what="returns per voxel"),
        "points": ArraySpec(("float32",), (r, 3), finite=True, what="x, y, z metres, map frame"),
        "votes": ArraySpec(_UNSIGNED, (r, t), what="votes per point and terrain class"),
        "session_hits": ArraySpec(_UNSIGNED, (r, None), what="returns per point and session"),
        "session_votes": ArraySpec(_UNSIGNED, (None, r, t), what="terrain votes per session"),
    }
    return specs[name]


def _empty(name: str, t: int) -> np.ndarray:
    shapes = {"sums": (0, 3), "points": (0, 3), "votes": (0, t), "session_hits": (0, 1), "session_votes": (1, 0, t)}
    dtype = {"keys": np.int64, "sums": np.float64, "points": np.float32}.get(name, np.uint8)
    return np.zeros(shapes.get(name, (0,)), dtype=dtype)


def capped_votes(votes: np.ndarray) -> np.ndarray:
    """Terrain votes as the read view stores them: uint16, capped at 65,535."""
    if votes.dtype.itemsize > 2:
        votes = np.minimum(votes, np.asarray(_U16_MAX, dtype=votes.dtype))
    return votes.astype(np.uint16)


def gather_rows(array: np.ndarray, order: np.ndarray) -> np.ndarray:
    """array[order] along the first axis, each row moved as one opaque item (several times faster than
    NumPy's fancy indexing of a 2-D array with few columns)."""
    array = np.ascontiguousarray(array)
    row = np.dtype((np.void, array.dtype.itemsize * int(np.prod(array.shape[1:], dtype=np.int64))))
    return array.view(row).reshape(-1)[order].view(array.dtype).reshape(-1, *array.shape[1:])


def stored_rows(bundle: Bundle, names: tuple[str, ...], n: int, k: int, t: int) -> dict[str, np.ndarray]:
    """`read_rows` of a chunked map with its rows in the read view's order (by voxel key), as the flat
    layout stores them: points, votes (exact), session_hits, session_votes and "counts" (a CSR
    matrix), for readers of a joined map's sessions (terra/mapping/changes.py, sessions.py)."""
    voxel = n > 0 and bundle.has(f"{chunk_folder(0)}/keys")
    rows = read_rows(bundle, (*names, *(("keys",) if voxel else ())), n, k, t)
    order = np.argsort(rows["keys"]) if voxel else np.arange(n)
    out: dict[str, np.ndarray] = {}
    for name in names:
        if name == "counts":
            counts = sp.csr_matrix((rows["counts_data"], rows["counts_indices"], rows["counts_indptr"]), shape=(n, k))
            out[name] = counts[order]  # pyright: ignore[reportArgumentType]  # csr indexing stays csr
        elif name == "session_votes":
            out[name] = rows[name][:, order]
        else:
            out[name] = gather_rows(rows[name], order)
    return out
