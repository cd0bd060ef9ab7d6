"""A bundle's map at a glance, for `terra info` (plain dict, JSON-ready)."""

from __future__ import annotations

from typing import Any

import numpy as np

from terra.bundle import Bundle
from terra.mapping.chunks import capped_votes, is_chunked, read_rows
from terra.mapping.sessions import session_list
from terra.npy import ArraySpec


def terrain_histogram(votes: np.ndarray, terrain_classes: list[str], min_share: float = 0.5) -> dict[str, int]:
    """Points per terrain class by majority vote (share >= min_share), plus 'none'."""
    votes = np.asarray(votes)
    total = votes.sum(axis=1)
    best = votes.argmax(axis=1) if votes.shape[1] else np.zeros(votes.shape[0], dtype=np.int64)
    top = votes[np.arange(votes.shape[0]), best] if votes.shape[1] else np.zeros(votes.shape[0])
    labelled = (total > 0) & (top >= min_share * total)
    counts = np.bincount(best[labelled], minlength=len(terrain_classes))
    out = {name: int(counts[i]) for i, name in enumerate(terrain_classes)}
    out["none"] = int(np.count_nonzero(~labelled))
    return out


def _terrain_votes(bundle: Bundle, n: int, k: int, t: int) -> np.ndarray:
    """(N, T) uint16 votes as the read view has them, from either map layout (terra/mapping/chunks.py)."""
    if is_chunked(bundle):
        return capped_votes(read_rows(bundle, ("votes",), n, k, t)["votes"])
    spec = ArraySpec(("uint16",), (n, t), what="votes per point and terrain class")
    return bundle.array("map/terrain_votes", spec, mmap=True)


def map_summary(bundle: Bundle) -> dict[str, Any]:
    """Counts, terrain histogram, skipped-frame counters and bytes per component of `bundle`."""
    manifest = bundle.model
    out: dict[str, Any] = {
        "path": str(bundle.path),
        "written_by": manifest.written_by,
        "schema_version": manifest.schema_version,
        "version": bundle.version,
        "embedder": manifest.embedder.model_dump(mode="json") if manifest.embedder is not None else None,
        "terrain_classes": list(manifest.terrain_classes),
        "bytes": bundle.component_bytes(),
    }
    info = bundle.model.components.map
    if info is not None and info.points is not None and (bundle.has("map/terrain_votes") or is_chunked(bundle)):
        votes = _terrain_votes(bundle, info.points, info.bank or 0, len(out["terrain_classes"]))
        out["map"] = {
            "points": info.points,
            "bank_entries": info.bank,
            "images": info.images,
            "observations": info.observations,
            "observed_points": info.observed_points,
            "terrain_points": terrain_histogram(votes, out["terrain_classes"]),
            "stats": info.stats,
            "version": info.version,
            "frames": info.frames,
            "time_span": info.time_span,
            "sources": [
                {k: source.get(k) for k in ("name", "first_frame", "frames")}
                for source in (info.sources or [])
                if isinstance(source, dict)
            ],
            "sessions": session_list([s for s in (info.sources or []) if isinstance(s, dict)]),
            "fusion_state": bundle.has("map/state/meta.json"),
            "wgs84_anchor": None if info.wgs84_anchor is None else info.wgs84_anchor.model_dump(mode="json"),
        }
    return out
