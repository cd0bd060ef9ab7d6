"""The read view of a chunked live version (terra/mapping/chunks.py), derived from the view this
process derived before (issue 25: a snapshot at most 200 ms at a million map points).

A chunked version keeps its per-point arrays in creation order (the order in which the fusion
first saw each point), and so does its read view: a live map only appends rows, and a point keeps
its row for as long as the session runs. The view of the next version is therefore the previous
view with the rows of the chunks whose files differ read again and the new rows appended: every
unchanged chunk's rows are copied from the previous view as one block, with no sort and no
random access. (The flat layout's voxel-key order, which the view kept before, moved every row of
the map on every version: merging the new keys and gathering the rows into their sorted places
took about 0.1 s of a snapshot at a million points.) A live version's map is thus the batch
map's rows in another order; the closing version of a session is in the flat layout, sorted by
voxel key, file for file the batch map's (terra/live/session.py).

The files of the changed chunks that the version itself wrote come from the writer's memory when it
ran in this process (a live session's own snapshot: BundleWriter.put_array with hand_over=True), still
checked against their size, identity and spec; only the files it kept from the version before
(such as a patched chunk's base files) are read.

A chunk is taken from the previous view when its view files (points, votes, counts, and its row
patch: terra/mapping/chunk_patches.py) have the SHA-256 of those the view was derived from; such a
chunk is still checked against its size and SHA-256 here, as a read would. A process keeps, per
bundle folder, those digests and only weak references to the view's arrays (`_Memo`): it holds no
copy of the map, and a view no reader holds any more is read in full again. A view's arrays are
read-only, so the rows the next view copies from them are the rows that were read.
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

from terra.mapping.chunks import (
    PATCH_VIEW_FILES,
    VIEW_FILES,
    capped_votes,
    chunk_count,
    chunk_folder,
    read_rows,
    stored_chunk_rows,
)

if TYPE_CHECKING:
    from terra.bundle import Bundle

_MEMOS: OrderedDict[str, _Memo] = OrderedDict()  # by the bundle folder's real path, most recent last
_MEMO_LIMIT = 4  # bundle folders remembered (a process serves one live map, or a few)
_LOCK = threading.Lock()


@dataclass(frozen=True)
class _Memo:
    """What a process keeps of the last view it derived of one bundle folder."""

    digests: list[dict[str, str]]  # per chunk: view file name -> SHA-256, of the files the view was derived from
    rows: int  # rows per chunk
    n: int  # rows of the view
    t: int  # terrain classes
    k: int  # bank entries (the counts' columns)
    arrays: tuple[weakref.ref, weakref.ref, weakref.ref]  # points, votes, counts

    def previous(self, rows: int, n: int, t: int, k: int) -> tuple[np.ndarray, np.ndarray, sp.csr_matrix] | None:
        """The view's points, votes and counts while a reader still holds them, when a version of
        `n` rows, `t` terrain classes and `k` bank entries in chunks of `rows` can continue it."""
        if rows != self.rows or t != self.t or n < self.n or k < self.k:  # a live map and its bank only grow
            return None
        points, votes, counts = (ref() for ref in self.arrays)
        return None if points is None or votes is None or counts is None else (points, votes, counts)


def view_files(c: int) -> list[str]:
    """The files of chunk `c` the read view is made of (those of its row patch included)."""
    return [f"{chunk_folder(c)}/{name}.npy" for name in (*VIEW_FILES, *PATCH_VIEW_FILES)]


def _digests(files: dict, c: int) -> dict[str, str]:
    """File name -> SHA-256 of the view files of chunk `c` that `files` (a manifest's files) holds."""
    return {name: files[name].sha256 for name in view_files(c) if name in files}


def chunk_view(bundle: Bundle, n: int, k: int, t: int) -> tuple[np.ndarray, np.ndarray, sp.csr_matrix]:
    """(points (N, 3) float32 metres, map frame; terrain votes (N, T) uint16; counts (N, K) CSR
    int32) of a chunked map, rows in creation order; from the previous view of the same folder
    where its chunks did not change (module docstring)."""
    rows = stored_chunk_rows(bundle)
    count = chunk_count(n, rows)
    digests = [_digests(bundle.files, c) for c in range(count)]
    key = os.path.realpath(bundle.path)
    with _LOCK:
        memo = _MEMOS.get(key)
    previous = memo.previous(rows, n, t, k) if memo is not None else None
    kept = np.zeros(count, dtype=bool)
    if previous is not None and memo is not None:
        for c in range(min(count, len(memo.digests))):
            same_rows = min(n, (c + 1) * rows) == min(memo.n, (c + 1) * rows)  # the growing chunk grew
            kept[c] = same_rows and bool(digests[c]) and digests[c] == memo.digests[c]
    for c in np.flatnonzero(kept):
        for name in digests[c]:
            bundle.check(name[: -len(".npy")])
    fresh = read_rows(bundle, ("points", "votes", "counts"), n, k, t, [int(c) for c in np.flatnonzero(~kept)])
    fresh["votes"] = capped_votes(fresh["votes"])
    fresh["counts_data"] = fresh["counts_data"].astype(np.int32)
    if previous is None:
        previous = (fresh["points"][:0], fresh["votes"][:0], sp.csr_matrix((0, k), dtype=np.int32))
    points, votes, counts = _assembled(previous, fresh, kept, n, rows, k)
    _remember(key, digests, rows, n, t, k, (points, votes, counts))
    return points, votes, counts


def _runs(kept: np.ndarray) -> list[tuple[bool, int, int]]:
    """(kept, first chunk, chunk after the last) of each run of chunks alike in `kept`."""
    edges = np.flatnonzero(np.diff(kept.astype(np.int8))) + 1
    starts = np.concatenate([[0], edges]).astype(int)
    stops = np.concatenate([edges, [kept.size]]).astype(int)
    return [(bool(kept[a]), int(a), int(b)) for a, b in zip(starts, stops, strict=True) if b > a]


def _assembled(
    previous: tuple[np.ndarray, np.ndarray, sp.csr_matrix],
    fresh: dict[str, np.ndarray],
    kept: np.ndarray,
    n: int,
    rows: int,
    k: int,
) -> tuple[np.ndarray, np.ndarray, sp.csr_matrix]:
    """The view's arrays: the rows of the `kept` chunks from the previous view, those of the others
    from `fresh` (read_rows of those chunks, one after the other), each run of chunks one block."""
    old_points, old_votes, old_counts = previous
    sources = {
        True: (old_points, old_votes, old_counts.indptr, old_counts.indices, old_counts.data),
        False: (fresh["points"], fresh["votes"], fresh["counts_indptr"], fresh["counts_indices"], fresh["counts_data"]),
    }
    points, votes, lengths, indices, data = [], [], [], [], []
    read = 0  # rows of `fresh` used so far
    for is_kept, first, stop in _runs(kept):
        lo, hi = first * rows, min(n, stop * rows)
        a, b = (lo, hi) if is_kept else (read, read + hi - lo)
        read += 0 if is_kept else hi - lo
        p, v, indptr, i, d = sources[is_kept]
        points.append(p[a:b])
        votes.append(v[a:b])
        lengths.append(np.diff(indptr[a : b + 1]))
        indices.append(i[indptr[a] : indptr[b]])
        data.append(d[indptr[a] : indptr[b]])
    indptr = np.zeros(n + 1, dtype=np.int64)
    if n:
        np.cumsum(np.concatenate(lengths), out=indptr[1:])
    cat = lambda parts, like: np.concatenate(parts) if parts else like[:0]  # noqa: E731
    counts = sp.csr_matrix(
        (cat(data, fresh["counts_data"]), cat(indices, fresh["counts_indices"]), indptr), shape=(n, k)
    )
    return cat(points, fresh["points"]), cat(votes, fresh["votes"]), counts


def forget(folder: str | os.PathLike[str]) -> None:
    """Let go of what this process kept of the last view of the bundle `folder`: a live session's
    close, whose last version is in the flat layout, derives no view from it."""
    with _LOCK:
        _MEMOS.pop(os.path.realpath(folder), None)


def _remember(
    key: str,
    digests: list[dict[str, str]],
    rows: int,
    n: int,
    t: int,
    k: int,
    view: tuple[np.ndarray, np.ndarray, sp.csr_matrix],
) -> None:
    """Keep what the next derivation of this folder needs; the view's arrays become read-only."""
    points, votes, counts = view
    for array in (points, votes, counts.indptr, counts.indices, counts.data):
        array.flags.writeable = False
    memo = _Memo(digests, rows, n, t, k, (weakref.ref(points), weakref.ref(votes), weakref.ref(counts)))
    with _LOCK:
        _MEMOS[key] = memo
        _MEMOS.move_to_end(key)
        while len(_MEMOS) > _MEMO_LIMIT:
            _MEMOS.popitem(last=False)
