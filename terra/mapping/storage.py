"""The metric-semantic map in a bundle: component `map/` (no pickle; DESIGN.md decision 1).

Arrays (all under `map/`):
  points (N, 3) float32 metres, map frame; terrain_votes (N, T) uint16;
  counts_indptr (N+1,) int64, counts_indices (nnz,) int32, counts_data (nnz,) uint8/16/32: the
  sparse (N, K) observation counts; bank (K, D) float16 unit rows; terrain_embeddings (T, D)
  float32; images/stamp (M,) float64 s, images/camera (M,) int16, images/T_map_cam (M, 4, 4)
  float64, images/embedding (M, D) float16; visibility/cells (C,) int64 voxel keys,
  visibility/indptr (C+1,) int64, visibility/images (nnz,) int32.
Derived per-point data, written so that a query process need not recompute it (optional: older
bundles without them compute them on load): ms_avg_norm (N,) float32 row norms of counts @ bank
with the bank as stored, ms_max_id (N,) int32 most observed bank id (-1 unobserved).
JSON: map/meta.json {voxel_size, visibility_cell_size, camera_names, classes, dataset}.
Manifest: "embedder" {name, dim}, "terrain_classes", "components" {"map": counts, config, stats}.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.sparse as sp

from terra.bundle import Bundle, BundleWriter
from terra.errors import TerraError
from terra.mapping.semantic_map import ImageTable, MetricSemanticMap, ms_avg_norms, ms_max_ids
from terra.mapping.visibility import VisibilityIndex
from terra.perception.text import normalize_rows

MAP_FORMAT = 1


def smallest_unsigned(values: np.ndarray) -> np.ndarray:
    """`values` (non-negative integers) in the smallest unsigned dtype that holds them."""
    top = int(values.max(initial=0))
    for dtype in (np.uint8, np.uint16, np.uint32):
        if top <= np.iinfo(dtype).max:
            return values.astype(dtype)
    return values.astype(np.uint64)


def write_map(
    writer: BundleWriter,
    msm: MetricSemanticMap,
    config: dict[str, Any] | None = None,
    stats: dict[str, int] | None = None,
    dataset: str = "",
    classes: list[dict] | None = None,
) -> None:
    """Put `msm` into the bundle being written as component `map/` and fill the manifest keys."""
    counts = msm.counts.tocsr()
    counts.sort_indices()
    writer.put_array("map/points", np.asarray(msm.points, dtype=np.float32))
    writer.put_array("map/terrain_votes", np.asarray(msm.terrain_votes, dtype=np.uint16))
    writer.put_array("map/counts_indptr", counts.indptr.astype(np.int64))
    writer.put_array("map/counts_indices", counts.indices.astype(np.int32))
    writer.put_array("map/counts_data", smallest_unsigned(counts.data))
    stored_bank = np.asarray(msm.bank, dtype=np.float16).reshape(-1, msm.dim)
    writer.put_array("map/bank", stored_bank)
    # From the bank as load_map will see it (float16, renormalised), so loaded norms are exact.
    writer.put_array("map/ms_avg_norm", ms_avg_norms(counts, normalize_rows(stored_bank.astype(np.float32))))
    writer.put_array("map/ms_max_id", ms_max_ids(counts).astype(np.int32))
    writer.put_array("map/terrain_embeddings", np.asarray(msm.terrain_embeddings, dtype=np.float32))
    images = msm.images
    writer.put_array("map/images/stamp", images.stamp.astype(np.float64))
    writer.put_array("map/images/camera", images.camera.astype(np.int16))
    writer.put_array("map/images/T_map_cam", images.T_map_cam.astype(np.float64))
    writer.put_array("map/images/embedding", images.embedding.astype(np.float16).reshape(-1, msm.dim))
    vis = msm.visibility
    if vis is not None:
        writer.put_array("map/visibility/cells", vis.cell_keys.astype(np.int64))
        writer.put_array("map/visibility/indptr", vis.indptr.astype(np.int64))
        writer.put_array("map/visibility/images", vis.images.astype(np.int32))
    meta = {
        "format": MAP_FORMAT,
        "voxel_size": float(msm.voxel_size),
        "visibility_cell_size": None if vis is None else float(vis.cell_size),
        "camera_names": list(images.camera_names),
        "dataset": dataset,
        "classes": classes or [],
    }
    writer.put_json("map/meta.json", meta)
    writer.manifest["embedder"] = {"name": msm.embedder, "dim": msm.dim}
    writer.manifest["terrain_classes"] = list(msm.terrain_classes)
    writer.manifest.setdefault("components", {})["map"] = {
        "points": len(msm),
        "bank": int(msm.bank.shape[0]),
        "images": len(images),
        "observations": int(counts.nnz),
        "observed_points": int(np.count_nonzero(np.diff(counts.indptr))),
        "config": config or {},
        "stats": stats or {},
    }


def load_map(bundle: Bundle) -> MetricSemanticMap:
    """The MetricSemanticMap stored in `bundle` (TerraError when it has none or it is malformed)."""
    if not bundle.has("map/points"):
        raise TerraError(f"{bundle.path}: bundle has no map component; build one with `terra map`")
    embedder = bundle.manifest.get("embedder") or {}
    if "name" not in embedder or "dim" not in embedder:
        raise TerraError(f"{bundle.path}/manifest.json: field 'embedder' must hold 'name' and 'dim'")
    dim = int(embedder["dim"])
    meta = bundle.json("map/meta.json")
    points = bundle.array("map/points")
    n = points.shape[0]
    if points.ndim != 2 or points.shape[1] != 3:
        raise TerraError(f"{bundle.path}/map/points.npy: expected (N, 3) metres, got shape {points.shape} (corrupt bundle)")
    for name in ("map/bank", "map/terrain_embeddings", "map/images/embedding"):
        shape = bundle.array(name, mmap=True).shape
        if len(shape) != 2 or shape[1] != dim:
            raise TerraError(f"{bundle.path}/{name}.npy: expected rows of the embedder's dimension {dim} (manifest.json 'embedder'), got shape {shape}")
    bank = normalize_rows(bundle.array("map/bank").astype(np.float32))
    indptr = bundle.array("map/counts_indptr")
    indices = bundle.array("map/counts_indices")
    data = bundle.array("map/counts_data").astype(np.int32)
    if indptr.shape != (n + 1,) or indices.shape != data.shape or (indices.size and int(indices.max()) >= bank.shape[0]):
        raise TerraError(f"{bundle.path}/map: counts arrays do not match {n} points and {bank.shape[0]} bank entries (corrupt bundle)")
    counts = sp.csr_matrix((data, indices, indptr), shape=(n, bank.shape[0]))
    images = ImageTable(
        stamp=bundle.array("map/images/stamp"),
        camera=bundle.array("map/images/camera"),
        T_map_cam=bundle.array("map/images/T_map_cam"),
        embedding=normalize_rows(bundle.array("map/images/embedding").astype(np.float32)),
        camera_names=list(meta.get("camera_names", [])),
    )
    visibility = None
    if bundle.has("map/visibility/cells"):
        visibility = VisibilityIndex(
            cell_size=float(meta["visibility_cell_size"]),
            cell_keys=bundle.array("map/visibility/cells"),
            indptr=bundle.array("map/visibility/indptr"),
            images=bundle.array("map/visibility/images"),
            image_positions=images.position,
        )
    msm = MetricSemanticMap(
        points=points,
        terrain_classes=list(bundle.manifest.get("terrain_classes", [])),
        terrain_votes=bundle.array("map/terrain_votes"),
        terrain_embeddings=bundle.array("map/terrain_embeddings").astype(np.float32),
        counts=counts,
        bank=bank,
        images=images,
        embedder=str(embedder["name"]),
        voxel_size=float(meta.get("voxel_size", 0.4)),
        visibility=visibility,
    )
    msm._avg_norm = _derived(bundle, "map/ms_avg_norm", n, np.float32)
    max_id = _derived(bundle, "map/ms_max_id", n, np.int32)
    if max_id is not None:
        if max_id.size and (int(max_id.max()) >= bank.shape[0] or int(max_id.min()) < -1):
            raise TerraError(f"{bundle.path}/map/ms_max_id.npy: ids outside -1..{bank.shape[0] - 1} (corrupt bundle)")
        msm._max_id = max_id.astype(np.int64)
    return msm


def _derived(bundle: Bundle, name: str, n: int, dtype: type) -> np.ndarray | None:
    """A stored per-point array of `n` rows, or None when the bundle predates it."""
    if not bundle.has(name):
        return None
    array = bundle.array(name)
    if array.shape != (n,) or array.dtype != dtype:
        raise TerraError(f"{bundle.path}/{name}.npy: expected ({n},) {np.dtype(dtype).name}, "
                         f"got {array.shape} {array.dtype} (corrupt bundle)")
    return array
