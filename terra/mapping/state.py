"""The fusion state kept in the bundle beside the map it gives, so a later run continues it exactly
(`terra map --append`, a live session resumed after a crash).

The read view `map/` already holds most of the state: observation counts, terrain votes (below
65,535), the image table and the visibility index. `map/state/` adds only what the view rounds
or drops, in the map's stored point order:
  voxel_keys (N,) int64, voxel_sums (N, 3) float64 metres, voxel_hits (N,) smallest unsigned integer type: the exact
  accumulators of the voxel centroids (absent for a map on the dataset's own global map);
  bank (K, D) float32: the bank at full precision (matching uses it; the view stores float16);
  votes (N, T) uint32: only when some vote count exceeds the view's uint16;
  session_hits (N, S) smallest unsigned integer type: LiDAR returns per point and session, only when
  the map has more than one session (with one, they are the voxel hits);
  session_votes (S, N, T) smallest unsigned integer type: terrain votes per session, likewise.
  meta.json: {format, geometry, next_frame, first_stamp, last_stamp, notes, run}.
Restoring in stored order rather than first-seen order changes no output: the stored order is the
voxel-key order, which `finish()` computes from the keys alone.
A live version (`write_live`) keeps these per-point parts (keys, sums, hits, exact votes, session
hits and votes) in its row chunks, in creation order (terra/mapping/chunks.py); `map/state/` then
holds the bank and meta.json only, and `restore_mapper` restores the fusion in creation order.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from terra.bundle import MANIFEST, Bundle, BundleWriter
from terra.datasets.base import ClassTable, GeoreferencedDataset
from terra.errors import TerraError
from terra.mapping.association import FixedMap, VoxelMap
from terra.mapping.bank import EmbeddingBank
from terra.mapping.chunks import CHUNK_ROWS, is_chunked, read_rows, write_chunks
from terra.mapping.config import MappingConfig
from terra.mapping.fusion import FusionStats, MapFusion
from terra.mapping.mapper import Mapper
from terra.mapping.semantic_map import MetricSemanticMap
from terra.mapping.storage import MapTables, set_map_component, write_map, write_map_tables
from terra.npy import ArraySpec, smallest_unsigned
from terra.perception.base import Perception

STATE_FORMAT = 1
_U16_MAX = int(np.iinfo(np.uint16).max)


def write_state(writer: BundleWriter, mapper: Mapper, run: dict[str, Any], chunked: bool = False) -> None:
    """Put the fusion state of `mapper` under `map/state/` (after `write_map` of its finished map).
    `run`: what a continuation must match (config, embedder, terrain classes; see `check_run`).
    chunked: the per-point parts are in the version's row chunks (terra/mapping/chunks.py)."""
    fusion = mapper.fusion
    _put_meta(writer, mapper, run)
    writer.put_array("map/state/bank", np.asarray(fusion.bank.vectors, dtype=np.float32).reshape(-1, fusion.dim))
    if chunked:
        return
    geometry = fusion.geometry
    n = geometry.size
    order = geometry.final_order()
    if isinstance(geometry, VoxelMap):
        voxels = geometry.state(order)
        writer.put_array("map/state/voxel_keys", voxels["keys"])
        writer.put_array("map/state/voxel_sums", voxels["sums"])
        writer.put_array("map/state/voxel_hits", smallest_unsigned(voxels["hits"]))
    if fusion.session_hits.shape[1] > 1:
        writer.put_array("map/state/session_hits", smallest_unsigned(fusion.session_counts()))
        writer.put_array("map/state/session_votes", smallest_unsigned(fusion.session_votes()))
    votes = fusion.votes[:n]
    if votes.size and int(votes.max()) > _U16_MAX:
        writer.put_array("map/state/votes", votes[order].astype(np.uint32))


def _put_meta(writer: BundleWriter, mapper: Mapper, run: dict[str, Any]) -> None:
    geometry = mapper.fusion.geometry
    writer.put_json(
        "map/state/meta.json",
        {
            "format": STATE_FORMAT,
            "geometry": "voxel" if isinstance(geometry, VoxelMap) else "fixed",
            "next_frame": int(mapper.next_frame),
            "first_stamp": mapper.first_stamp,
            "last_stamp": mapper.last_stamp,
            "notes": dict(sorted(mapper.stats.notes.items())),
            "run": run,
        },
    )


def has_state(bundle: Bundle) -> bool:
    return bundle.has("map/state/meta.json")


def state_meta(bundle: Bundle) -> dict[str, Any]:
    """`map/state/meta.json`, checked for the keys a continuation reads."""
    where = f"{bundle.path}/map/state/meta.json"
    if not has_state(bundle):
        raise TerraError(
            f"{bundle.path}: the map has no fusion state to continue (written before terra kept it); "
            "map the sources again in one run"
        )
    meta = bundle.json("map/state/meta.json")
    if not isinstance(meta, dict) or meta.get("format") != STATE_FORMAT:
        raise TerraError(f"{where}: expected a fusion state of format {STATE_FORMAT}")
    for key, kind in (("geometry", str), ("next_frame", int), ("notes", dict), ("run", dict)):
        if not isinstance(meta.get(key), kind) or isinstance(meta.get(key), bool):
            raise TerraError(f"{where}: field {key!r} must be a {kind.__name__}")
    if meta["geometry"] not in ("voxel", "fixed") or meta["next_frame"] < 0:
        raise TerraError(f"{where}: field 'geometry' must be voxel or fixed, 'next_frame' >= 0")
    return meta


def restore_mapper(bundle: Bundle, mapper: Mapper) -> None:
    """Load the state kept in `bundle` into `mapper` (freshly made with the bundle's config, embedder
    and terrain classes: `check_run` first), so its next frame continues the drive exactly."""
    meta = state_meta(bundle)
    fusion = mapper.fusion
    raw = _RawMap(bundle, fusion, meta["geometry"] == "voxel")
    if meta["geometry"] == "voxel":
        keys, sums, hits = raw.row("keys"), raw.row("sums"), raw.row("hits")
        if raw.n and int(hits.min()) < 1:
            raise TerraError(f"{bundle.path}/map: voxel hits must be >= 1")
        fusion.geometry = VoxelMap.from_state(
            fusion.config.fusion.voxel_size, {"keys": keys, "sums": sums, "hits": hits.astype(np.int64)}
        )
        sorted_keys = fusion.geometry.state(fusion.geometry.final_order())["keys"]
        if raw.n > 1 and np.any(np.diff(sorted_keys) <= 0):
            raise TerraError(f"{bundle.path}/map: a voxel key is stored twice (corrupt bundle)")
    else:
        fusion.geometry = FixedMap(raw.row("points"), fusion.config.fusion.gate)
    _restore_observations(raw, fusion)
    _restore_images(raw, fusion)
    _restore_session_hits(raw, fusion)
    stats = bundle.model.components.map.stats if bundle.model.components.map is not None else {}
    notes = {str(k): str(v) for k, v in meta["notes"].items()}
    fusion.stats = FusionStats({k: int(v) for k, v in stats.items()}, notes)
    fusion.untouch()  # the fusion now holds what the bundle's version holds
    mapper.next_frame = int(meta["next_frame"])
    mapper.first_stamp = _stamp(meta.get("first_stamp"))
    mapper.last_stamp = _stamp(meta.get("last_stamp"))


_UNSIGNED = ("uint8", "uint16", "uint32", "uint64")


class _RawMap:
    """The stored map's arrays as written (no renormalising), checked against the manifest's sizes;
    the per-point ones (`row`) in the order they are stored: by voxel key in the flat layout, in
    creation order in row chunks (terra/mapping/chunks.py)."""

    def __init__(self, bundle: Bundle, fusion: MapFusion, voxel: bool):
        info = bundle.model.components.map
        if info is None or info.points is None or info.bank is None or info.images is None:
            raise TerraError(f"{bundle.path}/manifest.json: components.map lacks the map's sizes")
        self.bundle = bundle
        self.n, self.k, self.m = int(info.points), int(info.bank), int(info.images)
        self.nnz = int(info.observations or 0)
        self.dim = fusion.dim
        self.t = len(fusion.terrain_classes)
        self._rows: dict[str, np.ndarray] | None = None
        if is_chunked(bundle):
            names = ["points", "votes", "counts", *(["keys", "sums", "hits"] if voxel else [])]
            if self.n and bundle.has("map/chunks/00000/session_hits"):
                names += ["session_hits", "session_votes"]
            self._rows = read_rows(bundle, tuple(names), self.n, self.k, self.t)

    def array(self, name: str, dtypes: tuple[str, ...], shape: tuple[int | None, ...]) -> np.ndarray:
        return self.bundle.array(name, ArraySpec(dtypes, shape, what="the map's fusion state"))

    def has_row(self, name: str) -> bool:
        if self._rows is not None:
            return name in self._rows
        return self.bundle.has(f"map/state/{name}")

    def row(self, name: str) -> np.ndarray:
        """Per-point array `name` (keys, sums, hits, points, votes, counts_indptr, counts_indices,
        counts_data, session_hits, session_votes)."""
        if self._rows is not None:
            return self._rows[name]
        n, t, nnz = self.n, self.t, self.nnz
        flat = {
            "keys": ("map/state/voxel_keys", ("int64",), (n,)),
            "sums": ("map/state/voxel_sums", ("float64",), (n, 3)),
            "hits": ("map/state/voxel_hits", _UNSIGNED, (n,)),
            "points": ("map/points", ("float32",), (n, 3)),
            "counts_indptr": ("map/counts_indptr", ("int64",), (n + 1,)),
            "counts_indices": ("map/counts_indices", ("int32",), (nnz,)),
            "counts_data": ("map/counts_data", _UNSIGNED, (nnz,)),
            "session_hits": ("map/state/session_hits", _UNSIGNED, (n, None)),
            "session_votes": ("map/state/session_votes", _UNSIGNED, (None, n, t)),
        }
        if name == "votes":  # exact votes where some count passed uint16, else the read view's
            if self.bundle.has("map/state/votes"):
                return self.array("map/state/votes", ("uint32",), (n, t))
            return self.array("map/terrain_votes", ("uint16",), (n, t))
        return self.array(*flat[name])


def _restore_observations(raw: _RawMap, fusion: MapFusion) -> None:
    """Terrain votes, the bank at full precision and the (point, entry) counts."""
    fusion.votes = np.array(raw.row("votes"), dtype=np.uint32)
    bank = raw.array("map/state/bank", ("float32",), (raw.k, raw.dim))
    fusion.bank = EmbeddingBank(fusion.dim, fusion.config.fusion.match_threshold, bank)
    indptr, indices, data = raw.row("counts_indptr"), raw.row("counts_indices"), raw.row("counts_data")
    rows = np.repeat(np.arange(raw.n, dtype=np.int64), np.diff(indptr))
    fusion.counts.keys = (rows << 32) | indices.astype(np.int64)
    fusion.counts.values = data.astype(np.int64)
    fusion.counts._pending, fusion.counts._pending_size = [], 0


def _restore_images(raw: _RawMap, fusion: MapFusion) -> None:
    """The image table and each image's visibility cells (sorted, as fusion keeps them)."""
    from terra.schemas import MapMeta

    meta = raw.bundle.document("map/meta.json", MapMeta)
    m = raw.m
    fusion.camera_names = list(meta.camera_names)
    fusion._image_stamp = [float(v) for v in raw.array("map/images/stamp", ("float64",), (m,))]
    fusion._image_camera = [int(v) for v in raw.array("map/images/camera", ("int16",), (m,))]
    fusion._image_pose = list(raw.array("map/images/T_map_cam", ("float64",), (m, 4, 4)).astype(np.float64))
    embedding = raw.array("map/images/embedding", ("float16",), (m, raw.dim)).astype(np.float32)
    fusion._image_embedding = list(embedding)
    if not raw.bundle.has("map/visibility/cells"):
        fusion._vis_cells = [np.zeros(0, np.int64) for _ in range(m)]
        return
    cells = raw.array("map/visibility/cells", ("int64",), (None,))
    indptr = raw.array("map/visibility/indptr", ("int64",), (cells.size + 1,))
    images = raw.array("map/visibility/images", ("int32",), (int(indptr[-1]) if indptr.size else 0,))
    cell_of_pair = np.repeat(cells, np.diff(indptr))
    order = np.lexsort((cell_of_pair, images))
    bounds = np.concatenate([[0], np.cumsum(np.bincount(images, minlength=m))]).astype(np.int64)
    sorted_cells = cell_of_pair[order]
    fusion._vis_cells = [sorted_cells[bounds[i] : bounds[i + 1]] for i in range(m)]


def _restore_session_hits(raw: _RawMap, fusion: MapFusion) -> None:
    """Returns per point and session; a one-session map's are its voxel hits (none on a fixed map)."""
    if raw.has_row("session_hits"):
        fusion.session_hits = np.array(raw.row("session_hits"), dtype=np.int64)
    elif isinstance(fusion.geometry, VoxelMap):
        fusion.session_hits = fusion.geometry.state()["hits"].reshape(-1, 1).astype(np.int64)
    else:
        fusion.session_hits = np.zeros((raw.n, 1), dtype=np.int64)
    fusion.session = fusion.session_hits.shape[1] - 1
    fusion.earlier_votes, fusion.votes_before = [], np.zeros_like(fusion.votes)
    if raw.has_row("session_votes"):
        votes = raw.row("session_votes").astype(np.uint32)
        if votes.shape[0] != fusion.session + 1:
            where, sessions = f"{raw.bundle.path}/map", fusion.session + 1
            raise TerraError(f"{where}: terrain votes of {votes.shape[0]} sessions, expected {sessions}")
        fusion.earlier_votes = list(votes[:-1])
        fusion.votes_before = fusion.votes[: raw.n] - votes[-1]


def _stamp(value: object) -> float | None:
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None


def run_description(config: MappingConfig, perception: Perception) -> dict:
    """What a continuation of the map must share with it: everything that changes the fused bytes
    (not where the perception cache lives, nor how often a run checkpoints)."""
    return {
        "config": config.model_dump(mode="json", exclude={"perception": {"cache"}, "checkpoint_every": True}),
        "embedder": [perception.embedder, int(perception.dim)],
        "terrain_classes": list(perception.terrain_classes),
    }


def wgs84_anchor(base: Bundle | None, source: object = None) -> dict[str, Any] | None:
    """The map frame's WGS84 anchor (terra.schemas.Wgs84Anchor fields): the base map's (later
    sources are fused in its frame), else the first source's when it knows one
    (terra.datasets.base.GeoreferencedDataset), else None."""
    if base is not None:
        info = base.model.components.map
        return None if info is None or info.wgs84_anchor is None else info.wgs84_anchor.model_dump(mode="json")
    return source.wgs84_anchor() if isinstance(source, GeoreferencedDataset) else None


def write_fused(
    writer: BundleWriter,
    mapper: Mapper,
    run: dict[str, Any],
    name: str,
    classes: ClassTable,
    sources: list[dict],
    anchor: dict[str, Any] | None = None,
) -> MetricSemanticMap:
    """Everything `mapper` has fused as component `map/` of the version being written: the map (as
    `write_map`, `name` the first source's), its fusion state, its sources, frames and time span,
    and the map frame's WGS84 `anchor` when known (`wgs84_anchor`).
    Returns the map written (its own arrays: frames fused later leave it as it is)."""
    msm = mapper.finish()
    write_map(
        writer,
        msm,
        config=mapper.config.model_dump(mode="json"),
        stats=mapper.stats.to_json(),
        dataset=name,
        classes=classes.to_json(),
    )
    write_state(writer, mapper, run)
    _record_run(writer, mapper, sources, anchor)
    return msm


def write_live(
    writer: BundleWriter,
    mapper: Mapper,
    run: dict[str, Any],
    name: str,
    classes: ClassTable,
    sources: list[dict],
    anchor: dict[str, Any] | None = None,
    chunk_rows: int = CHUNK_ROWS,
) -> int:
    """`write_fused` for a live version: the per-point arrays in chunks of `chunk_rows` rows in
    creation order, only the chunks changed since the version the writer starts from written again
    (terra/mapping/chunks.py); the map is not finished here (that is a sort of the whole map).
    Returns the chunks written."""
    fusion = mapper.fusion
    images = fusion.image_table()
    visibility = fusion.visibility_index(images.position)
    tables = MapTables(
        fusion.bank.vectors, mapper.perception.terrain_embeddings(), images, visibility, mapper.perception.embedder,
        list(fusion.terrain_classes), mapper.config.fusion.voxel_size,
    )  # fmt: skip
    write_map_tables(writer, tables, name, classes.to_json())
    written = write_chunks(writer, fusion, writer.base, chunk_rows)
    fusion.counts.compact()
    rows = fusion.counts.keys >> 32
    observed = int(np.count_nonzero(np.diff(rows))) + 1 if rows.size else 0
    sizes = {"points": fusion.geometry.size, "observations": rows.size}
    set_map_component(writer, fusion.bank.vectors, len(images), sizes, observed)
    config = mapper.config.model_dump(mode="json")
    writer.update_component("map", config=config, stats=mapper.stats.to_json(), chunk_rows=chunk_rows)
    write_state(writer, mapper, run, chunked=True)
    _record_run(writer, mapper, sources, anchor)
    return written


def _record_run(writer: BundleWriter, mapper: Mapper, sources: list[dict], anchor: dict[str, Any] | None) -> None:
    """The map's sources, frames, time span, WGS84 anchor and perception, in the manifest."""
    span = mapper.time_span()
    if sources and mapper.run_first_stamp is not None and mapper.last_stamp is not None:
        sources = [*sources[:-1], {**sources[-1], "time_span": [mapper.run_first_stamp, mapper.last_stamp]}]
    writer.update_component(
        "map",
        dataset={k: v for k, v in sources[0].items() if k not in ("first_frame", "time_span", "session")},
        sources=sources,
        frames=int(mapper.next_frame),
        time_span=None if span is None else [span[0], span[1]],
        version=writer.model.version,
        **({"wgs84_anchor": anchor} if anchor is not None else {}),
    )
    writer.set_perception(mapper.perception.describe())


def append_base(out: Path) -> Bundle:
    """The bundle `--append` continues: it must exist and keep its fusion state."""
    if not (out / MANIFEST).is_file():
        raise TerraError(f"{out}: no bundle to append to; map the first source without --append")
    base = Bundle(out)
    if not base.has_component("map"):
        raise TerraError(f"{out}: the bundle has no map to append to; map the first source without --append")
    state_meta(base)  # one line when the map keeps no state
    return base


def check_run(bundle: Bundle, run: dict[str, Any]) -> None:
    """TerraError naming the first difference between the bundle's recorded run and `run`."""
    recorded = state_meta(bundle)["run"]
    where = f"{bundle.path}/map/state/meta.json"
    for key, label in (("embedder", "embedder"), ("terrain_classes", "terrain classes")):
        if recorded.get(key) != run.get(key):
            raise TerraError(
                f"{where}: the map was fused with {label} {recorded.get(key)!r:.200}, "
                f"this run has {run.get(key)!r:.200}; continue it with the same {label}"
            )
    difference = _first_difference(recorded.get("config"), run.get("config"), "mapping")
    if difference is not None:
        raise TerraError(
            f"{where}: the map was fused with {difference}; continue it with the same mapping "
            "configuration (leave --config out to use the bundle's)"
        )


def _first_difference(old: Any, new: Any, path: str) -> str | None:
    if isinstance(old, dict) and isinstance(new, dict):
        for key in sorted(set(old) | set(new)):
            found = _first_difference(old.get(key), new.get(key), f"{path}.{key}")
            if found is not None:
                return found
        return None
    if old != new:
        return f"{path} = {old!r:.80}, this run has {new!r:.80}"
    return None
