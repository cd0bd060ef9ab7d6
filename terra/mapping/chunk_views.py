"""The read view of a chunked live version (terra/mapping/chunks.py), derived from the view this
process derived before (issue 25: a snapshot at most 200 ms at a million map points).

A chunked version keeps its per-point arrays in creation order; readers see them sorted by voxel
key, the order the flat layout stores (so `load_map` of a live version is the batch map). Sorting
the whole map on every load cost about 0.1 s at a million points: reading every chunk, an argsort
of the keys, moving every row to a random place. Between two versions of a live map most chunks
are the same files (the same SHA-256) and a point's voxel key never changes, so the next view is
the previous one with
  - the new points' keys merged into the previous sorted keys (a sort of the new keys alone and a
    searchsorted), and
  - the rows of the chunks whose files differ read again and put in their places;
every other row is moved in order, in one pass (no random access). The arrays are those a full
derivation gives (tests/live/test_chunk_views.py); a version that does not continue the previous
view (other chunk rows or terrain classes, fewer points, a changed key, the previous arrays freed)
is derived in full. Chunks that are not read are still checked against their size and SHA-256.

A process keeps, per bundle folder, what this needs of the last view it derived (`_Memo`: the chunk
files' digests, the keys in creation order and in view order, the order: 20 bytes a point) and
only weak references to the view's arrays: it holds no copy of the map, the view lives as long as
its readers (a live session keeps its latest snapshot). A view's arrays are read-only, so rows the
next view takes from them are the rows that were read.
"""

from __future__ import annotations

import os
import threading
import weakref
from collections import OrderedDict
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import scipy.sparse as sp

from terra.errors import TerraError
from terra.mapping.chunks import capped_votes, chunk_count, chunk_folder, gather_rows, read_rows, stored_chunk_rows

if TYPE_CHECKING:
    from terra.bundle import Bundle

_VIEW_FILES = ("points", "votes", "counts_indptr", "counts_indices", "counts_data")
_PATCH_VIEW_FILES = tuple(f"patch_{name}" for name in _VIEW_FILES) + ("patch_rows",)
_MEMOS: OrderedDict[str, _Memo] = OrderedDict()  # by the bundle folder's real path, most recent last
_MEMO_LIMIT = 4  # bundle folders remembered (a process serves one live map, or a few)
_LOCK = threading.Lock()
# Above this share of the rows to read again, the full derivation is faster: it gathers every row
# anyway, without the merge. On the campus drive, a version that rewrote every chunk loaded in 80 ms
# from the previous view against 42 ms in full; one that rewrote 6 of 10 chunks (66 % of the rows)
# in 41-57 ms against 80-84 ms.
MOST_CHANGED = 0.8


@dataclass(frozen=True)
class View:
    """A read view with what the next derivation needs: points (N, 3) float32 metres, map frame;
    votes (N, T) uint16; counts (N, K) CSR int32, rows in view order; keys (N,) int64 voxel keys in
    creation order (a fixed map: the row numbers), sorted_keys the same in view order; order (N,)
    the creation row of each view row."""

    points: np.ndarray
    votes: np.ndarray
    counts: sp.csr_matrix
    keys: np.ndarray
    sorted_keys: np.ndarray
    order: np.ndarray


@dataclass(frozen=True)
class _Memo:
    digests: dict[str, str]  # chunk file name -> SHA-256, of the files the view was derived from
    rows: int  # rows per chunk
    t: int  # terrain classes
    k: int  # bank entries (the counts' columns)
    voxel: bool
    keys: np.ndarray
    sorted_keys: np.ndarray
    order: np.ndarray
    arrays: tuple[weakref.ref, weakref.ref, weakref.ref]  # points, votes, counts

    def previous(self) -> tuple[np.ndarray, np.ndarray, sp.csr_matrix] | None:
        """The view's points, votes and counts while a reader still holds them."""
        points, votes, counts = (ref() for ref in self.arrays)
        return None if points is None or votes is None or counts is None else (points, votes, counts)


def view_files(c: int, voxel: bool) -> list[str]:
    """The files of chunk `c` the read view can be made of (those of its row patch included)."""
    names = (*_VIEW_FILES, *(("keys",) if voxel else ()), *_PATCH_VIEW_FILES)
    return [f"{chunk_folder(c)}/{name}.npy" for name in names]


def _digests(files: dict, c: int, voxel: bool) -> dict[str, str]:
    """File name -> SHA-256 of the view files of chunk `c` that `files` (a manifest's files) holds."""
    return {name: files[name].sha256 for name in view_files(c, voxel) if name in files}


def sorted_view(bundle: Bundle, n: int, k: int, t: int) -> tuple[np.ndarray, np.ndarray, sp.csr_matrix]:
    """(points (N, 3) float32, terrain votes (N, T) uint16, counts (N, K) CSR int32) of a chunked
    map in the read view's order (by voxel key; a fixed map's own order): the arrays the flat
    layout stores for the same map; from the previous view of the same folder where it can."""
    voxel = n > 0 and bundle.has(f"{chunk_folder(0)}/keys")
    key = os.path.realpath(bundle.path)
    with _LOCK:
        memo = _MEMOS.get(key)
    view = _from_previous(bundle, memo, n, k, t, voxel) if memo is not None else None
    if view is None:
        view = full_view(bundle, n, k, t, voxel)
    _remember(key, bundle, view, voxel, t)
    return view.points, view.votes, view.counts


def full_view(bundle: Bundle, n: int, k: int, t: int, voxel: bool) -> View:
    """The view derived from every chunk: an argsort of the keys, every row gathered."""
    rows = read_rows(bundle, ("points", "votes", "counts", *(("keys",) if voxel else ())), n, k, t)
    counts = sp.csr_matrix(
        (rows["counts_data"].astype(np.int32), rows["counts_indices"], rows["counts_indptr"]), shape=(n, k)
    )
    if not voxel:
        keys = np.arange(n, dtype=np.int64)  # a fixed map's rows are in their own order
        return View(rows["points"], capped_votes(rows["votes"]), counts, keys, keys, keys)
    # Keys are unique (checked below): any sort gives the one order. int32 row numbers gather faster.
    order = np.argsort(rows["keys"]).astype(_index_type(n))
    sorted_keys = gather_rows(rows["keys"], order)
    if n > 1 and np.any(np.diff(sorted_keys) == 0):
        raise TerraError(f"{bundle.path}/map/chunks: a voxel key is stored twice (corrupt bundle)")
    votes = capped_votes(gather_rows(rows["votes"], order))
    ordered: sp.csr_matrix = counts[order]  # pyright: ignore[reportAssignmentType]  # rows keep their sorted bank ids
    return View(gather_rows(rows["points"], order), votes, ordered, rows["keys"], sorted_keys, order)


def forget(folder: str | os.PathLike[str]) -> None:
    """Let go of what this process kept of the last view of the bundle `folder` (20 bytes a point):
    a live session's close, whose last version is in the flat layout, derives no view from it."""
    with _LOCK:
        _MEMOS.pop(os.path.realpath(folder), None)


def _index_type(n: int) -> type:
    return np.int32 if n < 2**31 else np.int64


def _remember(key: str, bundle: Bundle, view: View, voxel: bool, t: int) -> None:
    """Keep what the next derivation of this folder needs; the view's arrays become read-only."""
    arrays = (view.points, view.votes, view.counts.indptr, view.counts.indices, view.counts.data)
    for array in arrays:
        array.flags.writeable = False
    rows = stored_chunk_rows(bundle)
    digests = [_digests(bundle.files, c, voxel) for c in range(chunk_count(view.keys.size, rows))]
    memo = _Memo(
        {name: sha for chunk in digests for name, sha in chunk.items()},
        rows,
        t,
        int(view.counts.get_shape()[1]),
        voxel,
        view.keys,
        view.sorted_keys,
        view.order,
        (weakref.ref(view.points), weakref.ref(view.votes), weakref.ref(view.counts)),
    )
    with _LOCK:
        _MEMOS[key] = memo
        _MEMOS.move_to_end(key)
        while len(_MEMOS) > _MEMO_LIMIT:
            _MEMOS.popitem(last=False)


def _changed_chunks(bundle: Bundle, memo: _Memo, n: int, voxel: bool) -> list[int] | None:
    """The chunks of `bundle` whose view files differ from those the memo's view was derived from
    (the others are checked against their size and SHA-256 here, as a read would); None when an
    unchanged chunk would hold rows the previous view did not have."""
    changed = []
    for c in range(chunk_count(n, memo.rows)):
        now = _digests(bundle.files, c, voxel)
        if now and now == {name: memo.digests[name] for name in view_files(c, voxel) if name in memo.digests}:
            if min(n, (c + 1) * memo.rows) > memo.keys.size:
                return None
            for name in now:
                bundle.check(name[: -len(".npy")])
        else:
            changed.append(c)
    return changed


def _from_previous(bundle: Bundle, memo: _Memo, n: int, k: int, t: int, voxel: bool) -> View | None:
    """The view of `bundle` from the memo's previous view and the chunks that changed since (module
    docstring); None when the version does not continue that view."""
    previous = memo.previous()
    n_old = memo.keys.size
    fits = memo.voxel == voxel and memo.t == t and n >= n_old and stored_chunk_rows(bundle) == memo.rows
    if previous is None or not fits or memo.k > k:  # the bank only grows
        return None
    changed = _changed_chunks(bundle, memo, n, voxel)
    if changed is None or len(changed) * memo.rows > MOST_CHANGED * max(n, 1):
        return None
    rows = memo.rows
    fresh = read_rows(bundle, ("points", "votes", "counts", *(("keys",) if voxel else ())), n, k, t, changed)
    read = [np.arange(c * rows, min(n, (c + 1) * rows)) for c in changed]
    ids = np.concatenate(read) if read else np.zeros(0, np.int64)  # the rows read, ascending
    split = int(np.searchsorted(ids, n_old))  # ids[split:] are the new rows n_old .. n - 1
    fresh_keys = fresh["keys"] if voxel else ids
    if not np.array_equal(fresh_keys[:split], memo.keys[ids[:split]]):
        return None  # an old point's key changed: not a continuation of the previous view
    sorted_keys, order, is_new = _merged_order(bundle, memo, fresh_keys[split:], n)
    changed_mask = np.zeros(chunk_count(n, rows), dtype=bool)
    changed_mask[changed] = True
    from_fresh = changed_mask[order // rows]  # view rows taken from the chunks read
    keep = ~from_fresh[~is_new]  # rows of the previous view kept as they are
    starts = np.zeros(changed_mask.size, np.int64)  # where each chunk read starts among the rows read
    starts[changed] = np.concatenate([[0], np.cumsum([r.size for r in read])[:-1]]) if read else []
    source = order[from_fresh]
    local = starts[source // rows] + source % rows  # the row read of each view row taken from them
    points = _placed(previous[0], keep, from_fresh, gather_rows(fresh["points"], local))
    votes = _placed(previous[1], keep, from_fresh, capped_votes(gather_rows(fresh["votes"], local)))
    read_counts = sp.csr_matrix(
        (fresh["counts_data"].astype(np.int32), fresh["counts_indices"], fresh["counts_indptr"]), shape=(ids.size, k)
    )
    counts = _placed_rows(previous[2], keep, from_fresh, read_counts[local], k)  # pyright: ignore[reportArgumentType]
    keys = np.concatenate([memo.keys, fresh_keys[split:]])
    return View(points, votes, counts, keys, sorted_keys, order)


def _merged_order(bundle: Bundle, memo: _Memo, new_keys: np.ndarray, n: int) -> tuple[np.ndarray, ...]:
    """(sorted keys (N,), order (N,), is_new (N,) bool: the view rows of new points) with the keys of
    the points added since the memo's view (creation rows n_old ..) merged into its sorted keys."""
    n_old, m = memo.keys.size, new_keys.size
    by_key = np.argsort(new_keys)
    new_sorted = new_keys[by_key]
    at = np.searchsorted(memo.sorted_keys, new_sorted)
    hit = memo.sorted_keys[np.minimum(at, n_old - 1)] == new_sorted if n_old else np.zeros(m, dtype=bool)
    if np.any(hit) or (m > 1 and np.any(np.diff(new_sorted) == 0)):
        raise TerraError(f"{bundle.path}/map/chunks: a voxel key is stored twice (corrupt bundle)")
    is_new = np.zeros(n, dtype=bool)
    is_new[at + np.arange(m)] = True  # each new key lands after the old keys below it and the new ones before it
    order = np.empty(n, dtype=_index_type(n))
    order[is_new] = n_old + by_key
    order[~is_new] = memo.order
    sorted_keys = np.empty(n, dtype=np.int64)
    sorted_keys[is_new] = new_sorted
    sorted_keys[~is_new] = memo.sorted_keys
    return sorted_keys, order, is_new


def _placed(previous: np.ndarray, keep: np.ndarray, from_fresh: np.ndarray, fresh: np.ndarray) -> np.ndarray:
    """(N, ...) rows: the previous view's rows where `keep` (in order) at the view rows not
    `from_fresh`, and the rows `fresh` (in view order) at the others; each row moved as one item."""
    out = np.empty((from_fresh.size, *previous.shape[1:]), dtype=previous.dtype)
    if out.size == 0:
        return out
    flat = _items(out)
    flat[~from_fresh] = _items(previous)[keep]
    flat[from_fresh] = _items(fresh.astype(previous.dtype, copy=False))
    return out


def _items(array: np.ndarray) -> np.ndarray:
    """A view of `array` (C-contiguous) with each row one opaque item (moved faster than its columns)."""
    width = int(np.prod(array.shape[1:], dtype=np.int64))
    row = np.dtype((np.void, array.dtype.itemsize * width))
    return np.ascontiguousarray(array).reshape(array.shape[0], width).view(row).reshape(array.shape[0])


def _placed_rows(
    previous: sp.csr_matrix, keep: np.ndarray, from_fresh: np.ndarray, fresh: sp.csr_matrix, k: int
) -> sp.csr_matrix:
    """`_placed` for the rows of a CSR matrix (the observation counts, K columns)."""
    previous_lengths = np.diff(previous.indptr)
    lengths = np.empty(from_fresh.size, dtype=np.int64)
    lengths[~from_fresh] = previous_lengths[keep]
    lengths[from_fresh] = np.diff(fresh.indptr)
    indptr = np.zeros(from_fresh.size + 1, dtype=np.int64)
    np.cumsum(lengths, out=indptr[1:])
    entry_fresh = np.repeat(from_fresh, lengths)
    entry_kept = np.repeat(keep, previous_lengths)
    indices = np.empty(int(indptr[-1]), dtype=np.int32)
    indices[~entry_fresh] = previous.indices[entry_kept]
    indices[entry_fresh] = fresh.indices
    data = np.empty(int(indptr[-1]), dtype=np.int32)
    data[~entry_fresh] = previous.data[entry_kept]
    data[entry_fresh] = fresh.data
    return sp.csr_matrix((data, indices, indptr), shape=(from_fresh.size, k))
