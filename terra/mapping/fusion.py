"""Fusion of per-image (or per-scan) perception into the global metric-semantic map.

Per image, following the paper with the reference's defects fixed:
1. Visible scan points: projection with distortion, z > 0, bounds and a z-buffer.
2. Terrain: each visible point inside a terrain mask votes once for that terrain class.
3. Masks with more than `max_terrain_overlap` of their pixels on terrain are dropped.
4. Each remaining mask's visible points off terrain: DBSCAN in 3D, only the largest cluster keeps
   the mask.
5. The mask embedding is matched against the bank (>= 0.9 cosine reuses an entry, in order, so
   duplicates within one image share one) and the cluster's map points get one count each per
   (point, entry) per image, not per pixel.
6. The image's stamp, camera, camera pose, embedding and visibility cells are recorded.
Scans without images take terrain and object groups from their per-point labels through the same
steps 2, 4 and 5.
"""

from __future__ import annotations

import uuid
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from terra.errors import TerraError
from terra.geometry import CameraCalibration, invert_pose, transform_points, voxel_keys
from terra.mapping.association import FixedMap, VoxelMap, grown
from terra.mapping.bank import EmbeddingBank
from terra.mapping.clustering import largest_clusters
from terra.mapping.config import MappingConfig
from terra.mapping.projection import VisiblePoints, visible_points
from terra.mapping.semantic_map import FusionRows, ImageTable, MetricSemanticMap
from terra.mapping.visibility import VisibilityIndex, merged_pairs, sorted_pairs
from terra.perception.base import ImagePerception, PointPerception

_ENTRY_BITS = 32  # count pairs are packed as (map row << 32) | bank entry


@dataclass
class FusionStats:
    """Counters of what was fused, dropped and skipped (listed in the manifest and the summary)."""

    counts: dict[str, int] = field(default_factory=dict)
    notes: dict[str, str] = field(default_factory=dict)  # first message per fault counter

    def add(self, name: str, value: int = 1) -> None:
        self.counts[name] = self.counts.get(name, 0) + int(value)

    def note(self, name: str, message: str) -> None:
        self.notes.setdefault(name, message)

    def to_json(self) -> dict[str, int]:
        return dict(sorted(self.counts.items()))


class CountAccumulator:
    """Sparse (map point, bank entry) observation counts: appended pair keys, compacted by
    summing duplicates whenever enough have gathered."""

    def __init__(self, compact_every: int = 2_000_000):
        self.keys = np.zeros(0, dtype=np.int64)  # sorted unique pair keys
        self.values = np.zeros(0, dtype=np.int64)
        self._pending: list[np.ndarray] = []
        self._pending_size = 0
        self._compact_every = compact_every

    def add(self, rows: np.ndarray, entries: np.ndarray) -> None:
        """One observation per (row, entry) pair; duplicates within the call count once."""
        pairs = np.unique((np.asarray(rows, np.int64) << _ENTRY_BITS) | np.asarray(entries, np.int64))
        self._pending.append(pairs)
        self._pending_size += pairs.size
        if self._pending_size >= self._compact_every:
            self.compact()

    def compact(self) -> None:
        if not self._pending:
            return
        keys = np.concatenate([self.keys, *self._pending])
        weights = np.concatenate([self.values, np.ones(self._pending_size, dtype=np.int64)])
        self.keys, inverse = np.unique(keys, return_inverse=True)
        self.values = np.bincount(inverse, weights=weights).astype(np.int64)
        self._pending, self._pending_size = [], 0

    def to_csr(self, n_rows: int, n_cols: int, row_map: np.ndarray | None = None) -> sp.csr_matrix:
        """(n_rows, n_cols) int32 CSR; `row_map` renumbers rows (old -> new) first."""
        self.compact()
        rows = self.keys >> _ENTRY_BITS
        cols = self.keys & ((1 << _ENTRY_BITS) - 1)
        if row_map is not None:
            rows = row_map[rows]
        m = sp.coo_matrix((self.values.astype(np.int32), (rows, cols)), shape=(n_rows, n_cols)).tocsr()
        m.sort_indices()
        return m  # pyright: ignore[reportReturnType]  # scipy infers csr_array for coo_matrix.tocsr()


def _marked(mask: np.ndarray, rows: np.ndarray, size: int) -> np.ndarray:
    """Row mask `mask` with room for `size` rows and `rows` set (the array itself when it had room)."""
    mask = grown(mask, size)
    mask[rows] = True
    return mask


class MapFusion:
    """The incremental fusion state. `integrate_*` add observations; `finish()` gives the map."""

    def __init__(
        self, config: MappingConfig, terrain_classes: list[str], dim: int, global_map: np.ndarray | None = None
    ):
        self.config = config
        self.terrain_classes = list(terrain_classes)
        fusion = config.fusion
        self.geometry: VoxelMap | FixedMap = (
            FixedMap(global_map, fusion.gate) if global_map is not None else VoxelMap(fusion.voxel_size)
        )
        self.bank = EmbeddingBank(dim, fusion.match_threshold)
        self.counts = CountAccumulator()
        self.votes = np.zeros((0, len(self.terrain_classes)), dtype=np.uint32)
        self.camera_names: list[str] = []
        self._image_stamp: list[float] = []
        self._image_camera: list[int] = []
        self._image_pose: list[np.ndarray] = []
        self._image_embedding: list[np.ndarray] = []
        self._vis_cells: list[np.ndarray] = []  # per image: unique visibility cell keys
        # The visibility pairs of the first `_vis_sorted[0]` images, sorted (visibility.sorted_pairs):
        # the next index merges only the images added since (`visibility_index`).
        self._vis_sorted: tuple[int, np.ndarray, np.ndarray] = (0, np.zeros(0, np.int64), np.zeros(0, np.int32))
        self.stats = FusionStats()
        self.dim = int(dim)
        # LiDAR returns per (map point, session): which session saw which point (change detection
        # compares only what both saw). Column `session` is the session being fused.
        self.session_hits = np.zeros((0, 1), dtype=np.int64)
        self.session = 0
        # Terrain votes per session: the earlier sessions' (each (n, T), rows in creation order) and the
        # votes as they stood when the current session began (its own are the difference).
        self.earlier_votes: list[np.ndarray] = []
        self.votes_before = np.zeros((0, len(self.terrain_classes)), dtype=np.uint32)
        # Per map point (creation order): whether anything of its row changed since the last
        # committed version, so a version rewrites only the row chunks that changed
        # (terra/mapping/chunks.py). Every change of a row comes from a scan point associated to it.
        self.touched = np.zeros(0, dtype=bool)
        # The same since the last `finish`, and how many maps it made: the next map names the rows it
        # changed (FusionRows.changed), so a graph update recomputes only those (terra.graph.update).
        self.unfinished = np.zeros(0, dtype=bool)
        self.finished = 0
        self.id = uuid.uuid4().hex  # names this fusion's rows in the maps it makes (FusionRows)
        self.released = False

    def release(self) -> None:
        """Let go of the fusion state (the map's rows, votes, counts, bank and image table) once the
        map is committed for the last time, so a closing whole-map build does not hold it beside the
        stored map it reads; the stats are kept. A released fusion fuses nothing more."""
        self.geometry = VoxelMap(self.config.fusion.voxel_size)
        self.bank = EmbeddingBank(self.dim, self.config.fusion.match_threshold)
        self.counts = CountAccumulator()
        empty_votes = np.zeros((0, len(self.terrain_classes)), dtype=np.uint32)
        self.votes, self.votes_before, self.earlier_votes = empty_votes, empty_votes.copy(), []
        self.session_hits = np.zeros((0, 1), dtype=np.int64)
        self.touched, self.unfinished = np.zeros(0, dtype=bool), np.zeros(0, dtype=bool)
        for images in (self._image_stamp, self._image_camera, self._image_pose, self._image_embedding, self._vis_cells):
            images.clear()
        self._vis_sorted = (0, np.zeros(0, np.int64), np.zeros(0, np.int32))
        self.released = True

    # -- per frame --------------------------------------------------------------------------

    def associate(self, points_lidar: np.ndarray, T_map_lidar: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Scan (n, 3) LiDAR frame -> (points in the map frame (n, 3) float64, map index (n,))."""
        if self.released:  # its rows are gone: a new point would start another map
            raise TerraError(
                "this map's fusion state was let go of when its session closed; resume the bundle to go on"
            )
        points_map = transform_points(np.asarray(T_map_lidar, np.float64), np.asarray(points_lidar, np.float64))
        index = self.geometry.associate(points_map)
        self.votes = grown(self.votes, self.geometry.size)
        self.session_hits = grown(self.session_hits, self.geometry.size)
        rows, returns = np.unique(index[index >= 0], return_counts=True)
        self.session_hits[rows, self.session] += returns
        self.touched = _marked(self.touched, rows, self.geometry.size)
        self.unfinished = _marked(self.unfinished, rows, self.geometry.size)
        self.stats.add("points_unassociated", int(np.count_nonzero(index < 0)))
        return points_map, index

    def integrate_image(
        self,
        points_lidar: np.ndarray,
        points_map: np.ndarray,
        map_index: np.ndarray,
        T_map_lidar: np.ndarray,
        camera: CameraCalibration,
        stamp: float,
        seen: ImagePerception,
        visible: VisiblePoints | None = None,
    ) -> None:
        """Fuse one image's perception; `visible` may be passed when already computed."""
        proj = self.config.projection
        if visible is None:
            visible = visible_points(points_lidar, camera, proj.min_depth, proj.zbuffer_px)
        self._add_image(
            camera.name,
            stamp,
            np.asarray(T_map_lidar, np.float64) @ invert_pose(camera.T_cam_lidar),
            seen.image_embedding,
        )
        self._vis_cells.append(np.unique(voxel_keys(points_map[visible.index], self.config.visibility.cell_size)))
        self.stats.add("images_fused")
        rows = map_index[visible.index]
        terrain = seen.terrain[visible.rows, visible.cols]
        self._vote(rows, terrain)

        masks = seen.masks
        if len(masks) == 0:
            return
        pixels = masks.pixel_counts()
        on_terrain = masks.overlap_counts(seen.terrain >= 0)
        kept = np.flatnonzero((pixels > 0) & (on_terrain <= self.config.fusion.max_terrain_overlap * pixels))
        self.stats.add("masks", len(masks))
        self.stats.add("masks_dropped_terrain", len(masks) - kept.size)
        # A mask's points exclude terrain pixels (the reference blacked terrain out before
        # proposing masks), so the ground under an object keeps only its terrain vote.
        off_terrain = np.flatnonzero(terrain < 0)
        pix, mask = masks.subset(kept).members(visible.rows[off_terrain], visible.cols[off_terrain])
        pix = off_terrain[pix]
        self._fuse_groups(points_map[visible.index[pix]], rows[pix], mask, seen.mask_embeddings[kept])

    def integrate_points(self, points_map: np.ndarray, map_index: np.ndarray, seen: PointPerception) -> None:
        """Fuse a scan's per-point labels (sources without images)."""
        self._vote(map_index, seen.terrain)
        self.stats.add("masks", seen.group_embeddings.shape[0])
        self._fuse_groups(
            points_map[seen.group_point], map_index[seen.group_point], seen.group_index, seen.group_embeddings
        )

    def begin_session(self) -> None:
        """Count the frames fused from now on as a new session (a new column of `session_hits`)."""
        n = self.geometry.size
        self.earlier_votes.append(self._current_votes(n))
        self.votes_before = grown(self.votes, n)[:n].copy()
        self.session_hits = np.concatenate(
            [self.session_hits, np.zeros((self.session_hits.shape[0], 1), dtype=np.int64)], axis=1
        )
        self.session = self.session_hits.shape[1] - 1
        self.touch_all()  # every row gains a session column

    def touch_all(self) -> None:
        """Mark every row changed (its next version rewrites all of them)."""
        self.touched = np.ones(max(self.geometry.size, self.touched.shape[0]), dtype=bool)
        self.unfinished = np.ones_like(self.touched)

    def untouch(self) -> None:
        """Forget the changes: the version they went into is committed."""
        self.touched[:] = False

    def touched_rows(self) -> np.ndarray:
        """Rows (creation order) changed since the last `untouch`."""
        return np.flatnonzero(self.touched[: self.geometry.size])

    def session_counts(self) -> np.ndarray:
        """(N, S) LiDAR returns per map point (stored order) and session."""
        n = self.geometry.size
        return grown(self.session_hits, n)[:n][self.geometry.final_order()]

    def session_votes(self) -> np.ndarray:
        """(S, N, T) terrain votes per session, map point (stored order) and terrain class."""
        n = self.geometry.size
        parts = [grown(v, n)[:n] for v in self.earlier_votes] + [self._current_votes(n)]
        return np.stack(parts)[:, self.geometry.final_order()]

    def row_session_votes(self, start: int, stop: int) -> np.ndarray:
        """(S, stop - start, T) terrain votes per session of rows [start, stop) in creation order."""
        n = self.geometry.size
        current = grown(self.votes, n)[start:stop] - grown(self.votes_before, n)[start:stop]
        return np.stack([grown(v, n)[start:stop] for v in self.earlier_votes] + [current])

    def _earlier_votes_array(self) -> np.ndarray:
        """(S - 1, n, T) votes of the sessions before the current one, rows in creation order."""
        n, t = self.geometry.size, len(self.terrain_classes)
        if not self.earlier_votes:
            return np.zeros((0, n, t), dtype=np.uint32)
        return np.stack([grown(v, n)[:n] for v in self.earlier_votes]).astype(np.uint32)

    def _current_votes(self, n: int) -> np.ndarray:
        """(n, T) votes of the current session, rows in creation order."""
        return grown(self.votes, n)[:n] - grown(self.votes_before, n)[:n]

    def _vote(self, rows: np.ndarray, terrain: np.ndarray) -> None:
        ok = (rows >= 0) & (terrain >= 0)
        np.add.at(self.votes, (rows[ok], terrain[ok].astype(np.int64)), 1)

    def _fuse_groups(self, points_map: np.ndarray, rows: np.ndarray, group: np.ndarray, embeddings: np.ndarray) -> None:
        """DBSCAN per group, bank matching of the surviving groups, one count per (point, entry)."""
        fusion = self.config.fusion
        keep = largest_clusters(points_map, group, fusion.dbscan_eps, fusion.dbscan_min_samples, fusion.dbscan_voxel)
        surviving = np.unique(group[keep])
        self.stats.add("masks_fused", surviving.size)
        self.stats.add("masks_dropped_dbscan", embeddings.shape[0] - surviving.size)
        if surviving.size == 0:
            return
        entry_of_group = np.full(embeddings.shape[0], -1, dtype=np.int64)
        entry_of_group[surviving] = self.bank.match_or_append(embeddings[surviving])
        sel = keep & (rows >= 0)
        self.counts.add(rows[sel], entry_of_group[group[sel]])

    def _add_image(self, camera_name: str, stamp: float, T_map_cam: np.ndarray, embedding: np.ndarray) -> None:
        if camera_name not in self.camera_names:
            self.camera_names.append(camera_name)
        self._image_stamp.append(float(stamp))
        self._image_camera.append(self.camera_names.index(camera_name))
        self._image_pose.append(T_map_cam)
        self._image_embedding.append(np.asarray(embedding, dtype=np.float32).reshape(self.dim))

    # -- checkpoints ------------------------------------------------------------------------

    def state(self) -> tuple[dict[str, np.ndarray], dict]:
        """Everything needed to resume exactly: (arrays, JSON-able metadata)."""
        self.counts.compact()
        images = self.image_table()
        cells, image_ids = self.visibility_pairs()
        arrays = {
            "votes": self.votes[: self.geometry.size].copy(),
            "bank": self.bank.vectors.copy(),
            "count_keys": self.counts.keys,
            "count_values": self.counts.values,
            "image_stamp": images.stamp,
            "image_camera": images.camera,
            "image_pose": images.T_map_cam,
            "image_embedding": images.embedding,
            "vis_cells": cells,
            "vis_lengths": np.asarray([c.size for c in self._vis_cells], dtype=np.int64),
            "session_hits": self.session_hits[: self.geometry.size].copy(),
            "votes_before": grown(self.votes_before, self.geometry.size)[: self.geometry.size].copy(),
            "earlier_votes": self._earlier_votes_array(),
        }
        if isinstance(self.geometry, VoxelMap):
            arrays.update({f"voxel_{k}": v for k, v in self.geometry.state().items()})
        return arrays, {
            "camera_names": list(self.camera_names),
            "stats": self.stats.to_json(),
            "notes": dict(self.stats.notes),
        }

    def restore(self, arrays: dict[str, np.ndarray], meta: dict) -> None:
        """Load a `state()` into this (freshly constructed, same config) fusion."""
        if isinstance(self.geometry, VoxelMap):
            self.geometry = VoxelMap.from_state(
                self.geometry.voxel_size, {k[6:]: v for k, v in arrays.items() if k.startswith("voxel_")}
            )
        self.votes = np.array(arrays["votes"], dtype=np.uint32).reshape(-1, len(self.terrain_classes))
        self.bank = EmbeddingBank(self.dim, self.config.fusion.match_threshold, arrays["bank"])
        self.counts.keys = np.array(arrays["count_keys"], dtype=np.int64)
        self.counts.values = np.array(arrays["count_values"], dtype=np.int64)
        self.camera_names = list(meta["camera_names"])
        self._image_stamp = [float(v) for v in arrays["image_stamp"]]
        self._image_camera = [int(v) for v in arrays["image_camera"]]
        self._image_pose = list(np.array(arrays["image_pose"], dtype=np.float64).reshape(-1, 4, 4))
        self._image_embedding = list(np.array(arrays["image_embedding"], dtype=np.float32).reshape(-1, self.dim))
        bounds = np.concatenate([[0], np.cumsum(arrays["vis_lengths"])]).astype(np.int64)
        cells = np.array(arrays["vis_cells"], dtype=np.int64)
        self._vis_cells = [cells[bounds[i] : bounds[i + 1]] for i in range(len(bounds) - 1)]
        self._vis_sorted = (0, np.zeros(0, np.int64), np.zeros(0, np.int32))
        self.stats = FusionStats(dict(meta["stats"]), dict(meta.get("notes", {})))
        if "session_hits" in arrays:  # checkpoints written before sessions were counted have none
            self.session_hits = np.array(arrays["session_hits"], dtype=np.int64).reshape(self.votes.shape[0], -1)
            self.session = self.session_hits.shape[1] - 1
        if "votes_before" in arrays:
            self.votes_before = np.array(arrays["votes_before"], dtype=np.uint32)
            self.earlier_votes = [np.array(v, dtype=np.uint32) for v in arrays["earlier_votes"]]
        self.touch_all()  # nothing is known of the versions written before the checkpoint

    # -- results ----------------------------------------------------------------------------

    def image_table(self) -> ImageTable:
        m = len(self._image_stamp)
        return ImageTable(
            stamp=np.asarray(self._image_stamp, dtype=np.float64).reshape(m),
            camera=np.asarray(self._image_camera, dtype=np.int16).reshape(m),
            T_map_cam=np.asarray(self._image_pose, dtype=np.float64).reshape(m, 4, 4),
            embedding=np.asarray(self._image_embedding, dtype=np.float32).reshape(m, self.dim),
            camera_names=list(self.camera_names),
        )

    def visibility_pairs(self, first: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """(cell keys, image ids) of the visibility cells of every image from image `first` on."""
        added = self._vis_cells[first:]
        lengths = [c.size for c in added]
        cells = np.concatenate(added) if added else np.zeros(0, np.int64)
        return cells, np.repeat(np.arange(first, first + len(added), dtype=np.int64), lengths)

    def visibility_index(self, image_positions: np.ndarray) -> VisibilityIndex:
        """The visibility index of every image so far (camera centres `image_positions` (M, 3), metres,
        map frame): the pairs of the images added since the last call are sorted alone and merged
        into those of the images before (visibility.merged_pairs); every pair sorted again took
        15-25 ms of a live snapshot at a million points."""
        done, cells, images = self._vis_sorted  # reset wherever the images are (release, restore)
        cells, images = merged_pairs((cells, images), sorted_pairs(*self.visibility_pairs(done)))
        self._vis_sorted = (len(self._vis_cells), cells, images)
        return VisibilityIndex.from_sorted_pairs(cells, images, self.config.visibility.cell_size, image_positions)

    def finish(self, embedder: str, terrain_embeddings: np.ndarray) -> MetricSemanticMap:
        """The fused map, points in their stored order (voxel-key order for accumulated maps)."""
        order = self.geometry.final_order()
        n = self.geometry.size
        self.votes = grown(self.votes, n)
        new_row = np.empty(n, dtype=np.int64)
        new_row[order] = np.arange(n)
        changed = np.flatnonzero(grown(self.unfinished, n)[:n])
        self.unfinished[:] = False
        self.finished += 1
        images = self.image_table()
        return MetricSemanticMap(
            points=self.geometry.points()[order],
            terrain_classes=list(self.terrain_classes),
            terrain_votes=np.minimum(self.votes[:n][order], np.iinfo(np.uint16).max).astype(np.uint16),
            terrain_embeddings=np.asarray(terrain_embeddings, dtype=np.float32),
            counts=self.counts.to_csr(n, len(self.bank), new_row),
            bank=self.bank.vectors.copy(),
            images=images,
            embedder=embedder,
            voxel_size=self.config.fusion.voxel_size,
            visibility=self.visibility_index(images.position),
            fusion_rows=FusionRows(self.id, np.asarray(order, dtype=np.int64), new_row, self.finished, changed),
        )
