"""A Terra map as the metric-semantic map files of the authors' Phase 1, so their Phase 2 and 3
scripts can build on it (file names and shapes: reference_files).

How Terra's map becomes theirs:
- the bank: rows 0..T-1 are the text embeddings of the T terrain classes (their rows 0..C-1 embed
  the segmentation model's class names, which their Phase 2 requires to equal the terrain
  classes), then Terra's K bank entries;
- counts per map point: terrain votes under the terrain's row, object observations under
  T + bank entry (their counts are pixel hits; Terra's are one per image, so theirs are larger);
- global indices are the rows of the map's points, written as the dataset's global map
  global_pc/global_pc_{t}.npy, (N, 4) float32 with intensity 0, t = the last image stamp;
- images in Terra's order (per scan, per camera), named `camera{n}_images/cam{n}_img_{t}.jpg`
  with n from 1; `_itr{N}` with N = number of scans - 1 (the index of their last scan);
- images within `image_range` metres that saw a point, and the closest image at any range with its
  distance, from the map's visibility index (distances from the camera centre; theirs measure from
  the LiDAR).
- vectors (bank and images) of an embedder narrower than their 512 (Terra's default text model is
  384-d) get zero columns up to 512: their Phase 2 sums into torch.zeros(512); norms and cosines
  are unchanged.
Everything is written with pickle protocol 4 and torch.save (tensors on the CPU, float32): that is
their format. terra_reference.json beside them records what `terra import` needs and their files do
not say: the embedder and its true dimension (the padding is stripped again), the classes, and each
image's exact camera pose (their files keep no poses, so an import without it estimates them);
terra_visibility.npy holds the map's visibility index exactly (their per-point image sets merge
neighbouring cells, so a visibility rebuilt from them is wider and moves place embeddings).
"""

from __future__ import annotations

import pickle
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp

from terra import __version__
from terra.bundle import Bundle, array_bytes, dumps_json
from terra.interop import reference_files as rf
from terra.mapping.semantic_map import MetricSemanticMap
from terra.mapping.visibility import VisibilityIndex

PICKLE_PROTOCOL = 4


def scan_index(msm: MetricSemanticMap) -> int:
    """Their `_itr{N}`: the index of the last scan, here the number of distinct image stamps - 1."""
    return max(int(np.unique(msm.images.stamp).size) - 1, 0)


def reference_counts(msm: MetricSemanticMap) -> dict[int, dict[int, int]]:
    """{point: {row: count}} over the terrain rows then the bank rows (see the module docstring)."""
    votes = sp.csr_matrix(np.asarray(msm.terrain_votes, dtype=np.int64))
    both = sp.csr_matrix(sp.hstack([votes, msm.counts.astype(np.int64)], format="csr"))  # typed CSR (no copy)
    both.sort_indices()
    out: dict[int, dict[int, int]] = {}
    indptr, indices, data = both.indptr, both.indices.tolist(), both.data.tolist()
    for row in np.flatnonzero(np.diff(indptr)).tolist():
        a, b = indptr[row], indptr[row + 1]
        out[row] = dict(zip(indices[a:b], data[a:b]))
    return out


def image_maps(
    msm: MetricSemanticMap, image_range: float
) -> tuple[dict[int, set[int]], dict[int, set[int]], dict[int, float]]:
    """Per point seen by an image: images within `image_range` metres, {closest image}, its distance (m)."""
    within: dict[int, set[int]] = {}
    closest: dict[int, set[int]] = {}
    distance: dict[int, float] = {}
    if msm.visibility is None or len(msm.images) == 0:
        return within, closest, distance
    lists, nearest = msm.images_observing(msm.points, max_range=image_range)
    seen = np.flatnonzero(nearest >= 0)
    gap = np.linalg.norm(msm.images.position[nearest[seen]] - msm.points[seen].astype(np.float64), axis=1)
    for g, image, d in zip(seen.tolist(), nearest[seen].tolist(), gap.tolist()):
        closest[g] = {image}
        distance[g] = d
        if lists[g].size:
            within[g] = set(lists[g].tolist())
    return within, closest, distance


def _tensor_bytes(array: np.ndarray) -> bytes:
    import io

    import torch

    buffer = io.BytesIO()
    torch.save(torch.from_numpy(np.ascontiguousarray(array, dtype=np.float32)), buffer)
    return buffer.getvalue()


def reference_files(msm: MetricSemanticMap, image_range: float = 20.0) -> dict[str, bytes]:
    """{relative path: bytes} of every file of the export (no sidecar)."""
    n = scan_index(msm)
    width = stored_dim(msm)
    bank = np.vstack([rf.unit_rows(msm.terrain_embeddings), rf.unit_rows(msm.bank)]).reshape(-1, msm.dim)
    names = [rf.image_name(int(c), float(t)) for c, t in zip(msm.images.camera, msm.images.stamp)]
    within, closest, distance = image_maps(msm, image_range)
    last = float(msm.images.stamp.max()) if len(msm.images) else 0.0
    global_pc = np.zeros((len(msm), 4), dtype=np.float32)
    global_pc[:, :3] = msm.points

    def pickled(obj: Any) -> bytes:
        return pickle.dumps(obj, protocol=PICKLE_PROTOCOL)

    files = {
        rf.COUNTS.format(n=n): pickled(reference_counts(msm)),
        rf.BANK.format(n=n): _tensor_bytes(rf.padded(bank, width)),
        rf.IMAGE_EMBEDDINGS.format(n=n): _tensor_bytes(
            rf.padded(rf.unit_rows(msm.images.embedding).reshape(-1, msm.dim), width)
        ),
        rf.IMAGE_NAMES.format(n=n): pickled(names),
        rf.IMAGES_WITHIN.format(thr=rf.range_text(image_range), n=n): pickled(within),
        rf.CLOSEST_IMAGE.format(n=n): pickled(closest),
        rf.CLOSEST_DISTANCE.format(n=n): pickled(distance),
        rf.GLOBAL_PC.format(t=rf.stamp_text(last)): array_bytes(global_pc),
    }
    if msm.visibility is not None:
        files[rf.VISIBILITY] = array_bytes(visibility_pairs(msm.visibility))
    return files


def visibility_pairs(visibility: VisibilityIndex) -> np.ndarray:
    """(nnz, 2) int64 (cell key, image) pairs of the map's visibility index: what the per-point
    image sets of their format cannot say exactly (a point's set merges the cells around it)."""
    counts = np.diff(visibility.indptr)
    return np.column_stack([np.repeat(visibility.cell_keys, counts), visibility.images.astype(np.int64)])


def stored_dim(msm: MetricSemanticMap) -> int:
    """The width of the exported vectors: the map's dimension, zero-padded to their 512 when narrower."""
    return max(int(msm.dim), rf.REFERENCE_DIM)


def sidecar(msm: MetricSemanticMap, bundle: Bundle, image_range: float) -> dict[str, Any]:
    """What `terra import` needs and their files do not say (their scripts ignore this file).
    `image_poses`: per image its T_map_cam's top three rows, row-major (12 floats; JSON keeps
    float64 exactly)."""
    return {
        "written_by": f"terra {__version__}",
        "source_bundle": bundle.path.name,
        "embedder": {"name": msm.embedder, "dim": msm.dim},
        "stored_dim": stored_dim(msm),
        "visibility_pairs": None if msm.visibility is None else int(msm.visibility.nnz),
        "image_poses": np.asarray(msm.images.T_map_cam, np.float64)[:, :3, :].reshape(-1, 12).tolist(),
        "terrain_classes": list(msm.terrain_classes),
        "class_rows": len(msm.terrain_classes),
        "itr": scan_index(msm),
        "image_range_m": float(image_range),
        "camera_names": list(msm.images.camera_names),
        "voxel_size": float(msm.voxel_size),
        "visibility_cell_size": None if msm.visibility is None else float(msm.visibility.cell_size),
        "distances_from": "camera centre",
    }


def is_reference_export(folder: Path) -> bool:
    """Whether `folder` is an export of Terra's: its sidecar reads and validates
    (terra.schemas.ReferenceSidecar; TerraError from a malformed one)."""
    from terra.schemas import ReferenceSidecar, read_model

    path = Path(folder) / rf.SIDECAR
    return path.is_file() and read_model(path, ReferenceSidecar, "sidecar JSON file") is not None


def export_reference(bundle: Bundle, out: Path, overwrite: bool = False, image_range: float = 20.0) -> dict[str, Any]:
    """Write the bundle's map as the reference's MS-map files into folder `out` (atomically)."""
    from terra.bundle import atomic_folder, check_output_folder
    from terra.errors import TerraError
    from terra.mapping.storage import load_map

    if not np.isfinite(image_range) or image_range <= 0:
        raise TerraError(f"--image-range must be a positive number of metres, got {image_range}")
    check_output_folder(Path(out), overwrite, "Terra reference export", is_reference_export, rf.SIDECAR)
    msm = load_map(bundle)
    files = reference_files(msm, image_range)

    def fill(root: Path) -> None:
        for name, data in files.items():
            (root / name).parent.mkdir(parents=True, exist_ok=True)
            (root / name).write_bytes(data)
        (root / rf.SIDECAR).write_text(dumps_json(sidecar(msm, bundle, image_range)))

    atomic_folder(Path(out), fill, "export")
    return {
        "format": "terra-reference",
        "out": str(out),
        "itr": scan_index(msm),
        "points": len(msm),
        "bank_rows": len(msm.terrain_classes) + int(msm.bank.shape[0]),
        "images": len(msm.images),
        "files": sorted([*files, rf.SIDECAR]),
    }


__all__ = ["export_reference", "reference_files", "reference_counts", "image_maps", "scan_index"]
