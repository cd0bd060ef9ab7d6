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
This is the flat layout, which batch runs and a live session's closing version write. A live
version (components.map.chunk_rows set) stores points, terrain votes and counts in row chunks
instead (terra/mapping/chunks.py), without ms_avg_norm / ms_max_id; `load_map` reads both layouts
into the same map.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp

from terra.bundle import Bundle, BundleWriter
from terra.errors import TerraError
from terra.mapping.semantic_map import ImageTable, MetricSemanticMap, ms_avg_norms, ms_max_ids
from terra.mapping.visibility import VisibilityIndex
from terra.npy import ArraySpec, check_csr, smallest_unsigned
from terra.perception.text import normalize_rows
from terra.schemas import MapMeta

MAP_FORMAT = 1


@dataclass
class MapTables:
    """The parts of a map stored the same way in both layouts (flat, and chunked:
    terra/mapping/chunks.py): everything but the per-point arrays."""

    bank: np.ndarray  # (K, D) float32 unit rows
    terrain_embeddings: np.ndarray  # (T, D)
    images: ImageTable
    visibility: VisibilityIndex | None
    embedder: str
    terrain_classes: list[str]
    voxel_size: float

    @classmethod
    def of(cls, msm: MetricSemanticMap) -> MapTables:
        return cls(
            msm.bank, msm.terrain_embeddings, msm.images, msm.visibility, msm.embedder, list(msm.terrain_classes),
            msm.voxel_size,
        )  # fmt: skip


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
    stored_bank = write_map_tables(writer, MapTables.of(msm), dataset, classes)
    # From the bank as load_map will see it (float16, renormalised), so loaded norms are exact.
    writer.put_array("map/ms_avg_norm", ms_avg_norms(counts, normalize_rows(stored_bank.astype(np.float32))))
    writer.put_array("map/ms_max_id", ms_max_ids(counts).astype(np.int32))
    sizes = {"points": len(msm), "observations": int(counts.nnz)}
    set_map_component(writer, msm.bank, len(msm.images), sizes, int(np.count_nonzero(np.diff(counts.indptr))))
    writer.update_component("map", config=config or {}, stats=stats or {})


def set_map_component(writer: BundleWriter, bank: np.ndarray, images: int, sizes: dict, observed: int) -> None:
    """Manifest entry components.map with the stored map's counts (sizes: points, observations)."""
    writer.set_component(
        "map",
        {
            "points": int(sizes["points"]),
            "bank": int(bank.shape[0]),
            "images": int(images),
            "observations": int(sizes["observations"]),
            "observed_points": observed,
        },
    )


def write_map_tables(writer: BundleWriter, tables: MapTables, dataset: str, classes: list[dict] | None) -> np.ndarray:
    """Put the map's bank, terrain embeddings, image table, visibility index and map/meta.json
    into the version being written; set the embedder and terrain classes. Returns the bank as stored."""
    dim = int(tables.terrain_embeddings.shape[1]) if tables.bank.ndim != 2 else int(tables.bank.shape[1])
    stored_bank = np.asarray(tables.bank, dtype=np.float16).reshape(-1, dim)
    writer.put_array("map/bank", stored_bank)
    writer.put_array("map/terrain_embeddings", np.asarray(tables.terrain_embeddings, dtype=np.float32))
    images = tables.images
    writer.put_array("map/images/stamp", images.stamp.astype(np.float64))
    writer.put_array("map/images/camera", images.camera.astype(np.int16))
    writer.put_array("map/images/T_map_cam", images.T_map_cam.astype(np.float64))
    writer.put_array("map/images/embedding", images.embedding.astype(np.float16).reshape(-1, dim))
    vis = tables.visibility
    if vis is not None:
        writer.put_array("map/visibility/cells", vis.cell_keys.astype(np.int64))
        writer.put_array("map/visibility/indptr", vis.indptr.astype(np.int64))
        writer.put_array("map/visibility/images", vis.images.astype(np.int32))
    meta = {
        "format": MAP_FORMAT,
        "voxel_size": float(tables.voxel_size),
        "visibility_cell_size": None if vis is None else float(vis.cell_size),
        "camera_names": list(images.camera_names),
        "dataset": dataset,
        "classes": classes or [],
    }
    writer.put_json("map/meta.json", meta)
    writer.set_embedder(tables.embedder, dim)
    writer.set_terrain_classes(list(tables.terrain_classes))
    return stored_bank


def _map_info(bundle: Bundle) -> tuple[dict[str, int], MapMeta]:
    """The sizes every map array is checked against, from the manifest (N points, K bank entries,
    M images, D embedding dimension, T terrain classes, nnz observations), and map/meta.json."""
    model = bundle.model
    where = f"{bundle.path}/manifest.json"
    if model.embedder is None:
        raise TerraError(f"{where}: field 'embedder' must hold 'name' and 'dim'")
    info = model.components.map
    if info is None:
        raise TerraError(f"{where}: field 'components.map' is missing; rebuild the bundle with `terra map`")
    counts = {"points": info.points, "bank": info.bank, "images": info.images, "observations": info.observations}
    missing = [k for k, v in counts.items() if v is None]
    if missing:
        raise TerraError(f"{where}: field 'components.map.{missing[0]}' is missing (a count of the stored map)")
    sizes = {
        "N": info.points,
        "K": info.bank,
        "M": info.images,
        "nnz": info.observations,
        "D": model.embedder.dim,
        "T": len(model.terrain_classes),
    }
    return sizes, bundle.document("map/meta.json", MapMeta)


def _specs(sizes: dict[str, int], cameras: int) -> dict[str, ArraySpec]:
    """What each array of component map/ must be (module docstring), sized by the manifest."""
    n, k, m, d, t, nnz = (sizes[key] for key in ("N", "K", "M", "D", "T", "nnz"))
    return {
        "map/points": ArraySpec(("float32",), (n, 3), finite=True, what="x, y, z metres, map frame"),
        "map/terrain_votes": ArraySpec(("uint16",), (n, t), what="votes per point and terrain class"),
        "map/counts_indptr": ArraySpec(("int64",), (n + 1,), what="row pointer of the observation counts"),
        "map/counts_indices": ArraySpec(("int32",), (nnz,), what="bank ids of the observation counts"),
        "map/counts_data": ArraySpec(
            ("uint8", "uint16", "uint32", "uint64"), (nnz,), low=0, high=2**31 - 1, what="observation counts"
        ),
        "map/bank": ArraySpec(("float16",), (k, d), finite=True, what="bank entries x the embedder's dimension"),
        "map/terrain_embeddings": ArraySpec(
            ("float32",), (t, d), finite=True, what="terrain classes x the embedder's dimension"
        ),
        "map/images/stamp": ArraySpec(("float64",), (m,), finite=True, what="image stamps, seconds"),
        "map/images/camera": ArraySpec(
            ("int16",), (m,), low=0, high=max(cameras - 1, 0), what="camera index into map/meta.json camera_names"
        ),
        "map/images/T_map_cam": ArraySpec(("float64",), (m, 4, 4), finite=True, what="camera poses"),
        "map/images/embedding": ArraySpec(("float16",), (m, d), finite=True, what="images x the embedder's dimension"),
        "map/visibility/cells": ArraySpec(("int64",), (None,), what="sorted visibility cell keys"),
        "map/visibility/indptr": ArraySpec(("int64",), (None,), what="row pointer of the visibility index"),
        "map/visibility/images": ArraySpec(("int32",), (None,), what="image ids of the visibility index"),
        "map/ms_avg_norm": ArraySpec(("float32",), (n,), finite=True, low=0.0, what="MS-Avg row norms"),
        "map/ms_max_id": ArraySpec(("int32",), (n,), low=-1, high=max(k - 1, -1), what="most observed bank id"),
    }


def load_map(bundle: Bundle, max_ids: bool = True) -> MetricSemanticMap:
    """The MetricSemanticMap stored in `bundle`; TerraError (one line naming the file) when it has
    none or anything in it disagrees with the manifest: dtype, shape, finiteness, ranges, and the
    structure of the sparse counts and visibility index. Rows in voxel-key order (the flat layout),
    or in creation order in a live version (terra/mapping/chunk_views.py). max_ids: False checks the stored MS-Max
    ids but does not keep them (8 bytes a point; `ms_max_ids` computes them if asked), for callers
    that never use them, such as `terra build`."""
    from terra.mapping.chunk_views import chunk_view
    from terra.mapping.chunks import is_chunked

    chunked = is_chunked(bundle)
    if not bundle.has("map/points") and not chunked:
        raise TerraError(f"{bundle.path}: bundle has no map component; build one with `terra map`")
    sizes, meta = _map_info(bundle)
    embedder = bundle.model.embedder
    if embedder is None:
        raise TerraError(f"{bundle.path}/manifest.json: field 'embedder' is missing, but the bundle has a map")
    if sizes["M"] and not meta.camera_names:
        raise TerraError(
            f"{bundle.path}/map/meta.json: field 'camera_names' is empty, but the map has {sizes['M']} images"
        )
    specs = _specs(sizes, len(meta.camera_names))

    def array(name: str) -> np.ndarray:
        return bundle.array(name, specs[name])

    if chunked:  # a live version: rows in creation order (terra/mapping/chunk_views.py)
        points, votes, counts = chunk_view(bundle, sizes["N"], sizes["K"], sizes["T"])
        if counts.nnz != sizes["nnz"]:
            raise TerraError(f"{bundle.path}/map/chunks: {counts.nnz} observations, the manifest says {sizes['nnz']}")
    else:
        points, votes, counts = array("map/points"), array("map/terrain_votes"), _counts(bundle, array, sizes)
    bank = normalize_rows(array("map/bank").astype(np.float32))
    images = ImageTable(
        stamp=array("map/images/stamp"),
        camera=array("map/images/camera"),
        T_map_cam=array("map/images/T_map_cam"),
        embedding=normalize_rows(array("map/images/embedding").astype(np.float32)),
        camera_names=list(meta.camera_names),
    )
    msm = MetricSemanticMap(
        points=points,
        terrain_classes=list(bundle.model.terrain_classes),
        terrain_votes=votes,
        terrain_embeddings=array("map/terrain_embeddings").astype(np.float32),
        counts=counts,
        bank=bank,
        images=images,
        embedder=embedder.name,
        voxel_size=float(meta.voxel_size),
        visibility=_visibility(bundle, array, meta, images, sizes["M"]),
    )
    if bundle.has("map/ms_avg_norm"):
        msm._avg_norm = array("map/ms_avg_norm")
    if bundle.has("map/ms_max_id"):
        ids = array("map/ms_max_id")  # checked either way: a damaged file fails every command alike
        if max_ids:
            msm._max_id = ids.astype(np.int64)
    return msm


def _counts(bundle: Bundle, array, sizes: dict[str, int]) -> sp.csr_matrix:
    """The (N, K) observation counts, after checking their CSR structure."""
    indptr, indices = array("map/counts_indptr"), array("map/counts_indices")
    check_csr(indptr, indices, sizes["N"], sizes["K"], f"{bundle.path}/map/counts_*.npy")
    data = array("map/counts_data").astype(np.int32)
    return sp.csr_matrix((data, indices, indptr), shape=(sizes["N"], sizes["K"]))


def _visibility(bundle: Bundle, array, meta: MapMeta, images: ImageTable, m: int) -> VisibilityIndex | None:
    if not bundle.has("map/visibility/cells"):
        return None
    where = f"{bundle.path}/map/visibility"
    if meta.visibility_cell_size is None:
        raise TerraError(
            f"{bundle.path}/map/meta.json: field 'visibility_cell_size' is missing, but the map has a visibility index"
        )
    cells, indptr, image_ids = (array(f"map/visibility/{name}") for name in ("cells", "indptr", "images"))
    if cells.size > 1 and np.any(np.diff(cells) <= 0):
        raise TerraError(f"{where}/cells.npy: cell keys must be strictly increasing (corrupt bundle)")
    check_csr(indptr, image_ids, cells.shape[0], m, f"{where}/*.npy")
    return VisibilityIndex(
        cell_size=float(meta.visibility_cell_size),
        cell_keys=cells,
        indptr=indptr,
        images=image_ids,
        image_positions=images.position,
    )
