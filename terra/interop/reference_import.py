"""The authors' metric-semantic map files (reference_files) as a Terra bundle.

What their files give: the global map's points (the dataset's global_pc), per point the counts of
bank entries (rows 0..C-1 of the bank embed the C terrain class names, so counts there are terrain
votes; the rest are object observations), the bank, each image's whole-image embedding and name
(camera and stamp), which images within their range (20 m) saw each point, and each point's
closest image with its distance.

What they cannot give, and how the bundle copes:
- the terrain class names (their Phase 2 takes them from its config): from Terra's sidecar, else
  `terrain_classes` (the segmentation model's names in order) is required;
- the embedder's name: from the sidecar, else `embedder` (default "clip-vit-b-16", ViT-B/16 CLIP,
  the paper's model); queries need a text embedder registered under that name;
- the embedder's dimension: vectors wider than it (Terra's export pads 384-d vectors to their 512
  with zero columns) are cut back to it when the extra columns are all zero; any other mismatch
  between the vectors and the named embedder is refused before anything is written;
- per-image poses: from Terra's sidecar when it records them (exact), else each image's position
  is recovered by trilateration from the points whose closest image it is (their ranges; at least
  4 points), else taken from the other cameras of the same scan, else the centroid of the points it
  saw; orientation is then unknown (identity). The manifest counts how each position was found;
- per-image visibility: from Terra's terra_visibility.npy when the sidecar records it (exact),
  else rebuilt from "images within range" and "closest image" as visibility cells, so Phase 2's
  20 m image rule works as on a map Terra made (a point's image set merges the cells around it,
  so the rebuilt index is somewhat wider than the one that wrote the files).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp

from terra.bundle import BundleWriter
from terra.errors import TerraError
from terra.geometry import voxel_keys
from terra.interop import reference_files as rf
from terra.interop.results import ImportResult
from terra.mapping.semantic_map import ImageTable, MetricSemanticMap
from terra.mapping.visibility import VisibilityIndex

DEFAULT_EMBEDDER = "clip-vit-b-16"
MIN_RANGES = 4  # points with a range needed to trilaterate one image position
MAX_RANGES = 400  # ranges used per image (evenly subsampled)
MAX_CAMERAS = 1024  # camera numbers in image names (stored as int16)


@dataclass
class ReferenceFiles:
    """The parsed contents of one save (`itr`) of a reference output folder."""

    folder: Path
    itr: int
    points: np.ndarray  # (N, 3) float32, metres, map frame
    counts: sp.csr_matrix  # (N, K) pixel-hit counts per bank row
    bank: np.ndarray  # (K, D) float32
    image_embedding: np.ndarray  # (M, D) float32
    image_camera: np.ndarray  # (M,) int16, 0-based
    image_stamp: np.ndarray  # (M,) float64 s
    within_pairs: np.ndarray  # (n, 2) int64 (point, image) pairs within the range
    closest: np.ndarray  # (N,) int64 closest image per point, -1 none
    closest_distance: np.ndarray  # (N,) float64 metres, nan none
    image_range: float | None
    sidecar: dict[str, Any]


def latest_itr(folder: Path) -> int:
    """The largest N of gidx2clipcounts_dict_itr{N}.pkl (the save their Phase 2 uses)."""
    found = [
        int(m.group(1))
        for p in folder.glob("gidx2clipcounts_dict_itr*.pkl")
        if (m := re.fullmatch(r"gidx2clipcounts_dict_itr(\d+)\.pkl", p.name))
    ]
    if not found:
        raise TerraError(
            f"{folder}: no gidx2clipcounts_dict_itr{{N}}.pkl; not an output folder of the reference's ms_map"
        )
    return max(found)


def _global_pc(folder: Path, given: Path | None) -> Path:
    """The global map file: `given` (a file, or a folder holding global_pc/ or global_pc_*.npy),
    else folder/global_pc/; the largest timestamp wins, as in the reference."""
    candidates = [given] if given is not None else [folder]
    for place in candidates:
        place = Path(place)
        if place.is_file():
            return place
        for sub in (place / "global_pc", place):
            files = sorted(sub.glob("global_pc_*.npy"), key=lambda p: _stamp_of(p))
            if files:
                return files[-1]
    where = given if given is not None else folder / "global_pc"
    raise TerraError(f"{where}: no global_pc_{{t}}.npy; give the dataset's global map with --global-pc")


def _stamp_of(path: Path) -> float:
    try:
        return float(path.stem.rsplit("_", 1)[-1])
    except ValueError:
        raise TerraError(f"{path}: expected global_pc_{{t}}.npy with t in seconds") from None


def _load_points(path: Path) -> np.ndarray:
    from terra.npy import read_npy

    array = read_npy(path, what="global map")
    if array.ndim != 2 or array.shape[1] < 3 or not np.issubdtype(array.dtype, np.number):
        raise TerraError(f"{path}: expected an (N, 4) array of x, y, z, intensity, got {array.dtype} {array.shape}")
    points = np.asarray(array[:, :3], dtype=np.float32)
    if not np.isfinite(points).all():
        raise TerraError(f"{path}: holds non-finite coordinates")
    return points


def _counts(path: Path, n_points: int, n_rows: int) -> sp.csr_matrix:
    data = rf.as_dict(rf.load_pickle(path), path, "{global_idx: {clip_id: count}}")
    rows, cols, values = [], [], []
    for g, per_point in data.items():
        g = rf.as_index(g, path, "global indices")
        for k, c in rf.as_dict(per_point, path, "of counts per point").items():
            rows.append(g)
            cols.append(rf.as_index(k, path, "clip ids"))
            values.append(rf.as_index(c, path, "counts"))
    rows_a, cols_a = np.asarray(rows, np.int64), np.asarray(cols, np.int64)
    if rows_a.size and rows_a.max() >= n_points:
        raise TerraError(
            f"{path}: global index {int(rows_a.max())} is past the global map's {n_points} points "
            "(another dataset's map?)"
        )
    if cols_a.size and cols_a.max() >= n_rows:
        raise TerraError(f"{path}: clip id {int(cols_a.max())} is past the bank's {n_rows} rows")
    return sp.csr_matrix((np.asarray(values, np.int64), (rows_a, cols_a)), shape=(n_points, n_rows))


def _image_names(path: Path, count: int) -> tuple[np.ndarray, np.ndarray]:
    names = rf.load_pickle(path)
    if not isinstance(names, list) or len(names) != count:
        size = len(names) if isinstance(names, list) else type(names).__name__
        raise TerraError(
            f"{path}: expected a list of {count} image names (one per row of the image embeddings), got {size}"
        )
    camera, stamp = np.zeros(count, np.int16), np.zeros(count, np.float64)
    for i, name in enumerate(names):
        match = rf.IMAGE_NAME.search(name) if isinstance(name, str) else None
        n = int(match.group(1)) if match and len(match.group(1)) < 6 else 0
        t = float(match.group(3)) if match else np.nan
        if match is None or match.group(1) != match.group(2) or not 1 <= n <= MAX_CAMERAS or not np.isfinite(t):
            raise TerraError(
                f"{path}: image name {i} is {rf.shown(name)}, expected 'camera{{n}}_images/cam{{n}}_img_{{t}}.jpg' "
                f"(n from 1 to {MAX_CAMERAS}, t finite seconds)"
            )
        camera[i], stamp[i] = n - 1, t
    return camera, stamp


def _image_sets(path: Path, n_points: int, n_images: int, what: str) -> tuple[np.ndarray, np.ndarray]:
    """(points, images) pairs of a {global_idx: set(img_idx)} file."""
    data = rf.as_dict(rf.load_pickle(path), path, "{global_idx: set(img_idx)}")
    points, images = [], []
    for g, value in data.items():
        g = rf.as_index(g, path, "global indices")
        for i in rf.as_index_set(value, path, what):
            points.append(g)
            images.append(i)
    p, i = np.asarray(points, np.int64), np.asarray(images, np.int64)
    if p.size and p.max() >= n_points:
        raise TerraError(f"{path}: global index {int(p.max())} is past the global map's {n_points} points")
    if i.size and i.max() >= n_images:
        raise TerraError(f"{path}: image index {int(i.max())} is past the {n_images} saved images")
    return p, i


def _closest(folder: Path, itr: int, n_points: int, n_images: int) -> tuple[np.ndarray, np.ndarray]:
    """(N,) closest image per point (-1 none) and (N,) its range in metres (nan none)."""
    closest = np.full(n_points, -1, np.int64)
    distance = np.full(n_points, np.nan)
    image_path, dist_path = folder / rf.CLOSEST_IMAGE.format(n=itr), folder / rf.CLOSEST_DISTANCE.format(n=itr)
    if not image_path.is_file() or not dist_path.is_file():
        return closest, distance
    p, i = _image_sets(image_path, n_points, n_images, "closest images")
    # Points listed with several "closest" images (their file can hold more) keep no single one.
    unique, counts = np.unique(p, return_counts=True)
    single = np.isin(p, unique[counts == 1])
    closest[p[single]] = i[single]
    ranges = rf.as_dict(rf.load_pickle(dist_path), dist_path, "{global_idx: range_m}")
    for g, d in ranges.items():
        g = rf.as_index(g, dist_path, "global indices")
        if g >= n_points:
            raise TerraError(f"{dist_path}: global index {g} is past the global map's {n_points} points")
        distance[g] = rf.as_range(d, dist_path, g)
    return closest, distance


def _within(folder: Path, itr: int, n_points: int, n_images: int) -> tuple[np.ndarray, float | None]:
    files = sorted(folder.glob(f"gidx2imgs_*m_dict_itr{itr}.pkl"))
    if not files:
        return np.zeros((0, 2), np.int64), None
    path = files[0]
    match = re.fullmatch(rf"gidx2imgs_(.+)m_dict_itr{itr}\.pkl", path.name)
    image_range = rf.range_from_name(path, match.group(1)) if match else None
    p, i = _image_sets(path, n_points, n_images, "images within range")
    return np.column_stack([p, i]), image_range


def read_reference(folder: Path, itr: int | None = None, global_pc: Path | None = None) -> ReferenceFiles:
    """Parse and check one save of a reference output folder (TerraError naming the file)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise TerraError(f"{folder}: not a folder")
    itr = latest_itr(folder) if itr is None else int(itr)
    for name in (rf.COUNTS, rf.BANK, rf.IMAGE_EMBEDDINGS, rf.IMAGE_NAMES):
        if not (folder / name.format(n=itr)).is_file():
            raise TerraError(f"{folder / name.format(n=itr)}: missing (every save has it)")
    sidecar = _sidecar(folder)
    points = _load_points(_global_pc(folder, global_pc))
    bank = rf.load_tensor(folder / rf.BANK.format(n=itr))
    images = rf.load_tensor(folder / rf.IMAGE_EMBEDDINGS.format(n=itr))
    if bank.ndim != 2 or images.ndim != 2 or images.shape[1] != bank.shape[1]:
        raise TerraError(f"{folder}: bank {bank.shape} and image embeddings {images.shape} must be (K, D) and (M, D)")
    counts = _counts(folder / rf.COUNTS.format(n=itr), len(points), bank.shape[0])
    camera, stamp = _image_names(folder / rf.IMAGE_NAMES.format(n=itr), images.shape[0])
    within, image_range = _within(folder, itr, len(points), images.shape[0])
    closest, distance = _closest(folder, itr, len(points), images.shape[0])
    return ReferenceFiles(
        folder, itr, points, counts, bank, images, camera, stamp, within, closest, distance, image_range, sidecar
    )


def _sidecar(folder: Path) -> dict[str, Any]:
    """Terra's sidecar beside exported files (terra.schemas.ReferenceSidecar), {} without one."""
    from terra.schemas import ReferenceSidecar, read_model

    path = folder / rf.SIDECAR
    if not path.exists():
        return {}
    return read_model(path, ReferenceSidecar, "sidecar JSON file").model_dump(exclude_none=True)


# ------------------------------------------------------------------------------ image positions


def _trilaterate(points: np.ndarray, ranges: np.ndarray) -> np.ndarray:
    """The position (3,) whose distances to `points` (n, 3) best match `ranges` (n,): linear least
    squares, then a nonlinear refinement; of mirror solutions (points near one plane) the higher."""
    from scipy.optimize import least_squares

    mean = points.mean(axis=0)
    a = 2.0 * (points - mean)
    b = (points**2).sum(axis=1) - (points**2).sum(axis=1).mean() - ranges**2 + (ranges**2).mean()
    linear = np.linalg.lstsq(a, b, rcond=None)[0]

    def residual(c: np.ndarray) -> np.ndarray:
        return np.linalg.norm(points - c, axis=1) - ranges

    starts = [linear, np.array([linear[0], linear[1], max(linear[2], float(np.median(points[:, 2])) + 2.0)])]
    fits = [least_squares(residual, s, method="lm") for s in starts]
    best = min(fits, key=lambda f: (round(float(f.cost), 6), -float(f.x[2])))
    return np.asarray(best.x, dtype=np.float64)


def recorded_poses(ref: ReferenceFiles) -> np.ndarray | None:
    """(M, 4, 4) T_map_cam from the sidecar's `image_poses`, None when it records none; TerraError
    when it records poses for another number of images or rotations that are not rotations."""
    rows = ref.sidecar.get("image_poses")
    if rows is None:
        return None
    m = ref.image_embedding.shape[0]
    path = ref.folder / rf.SIDECAR
    if len(rows) != m:
        raise TerraError(f"{path}: field 'image_poses' holds {len(rows)} poses for {m} saved images")
    pose = np.tile(np.eye(4), (m, 1, 1))
    pose[:, :3, :] = np.asarray(rows, np.float64).reshape(m, 3, 4)
    rotation = pose[:, :3, :3]
    error = np.abs(rotation @ rotation.transpose(0, 2, 1) - np.eye(3)).max(initial=0.0)
    if error > 1e-6 or (m and np.linalg.det(rotation).min() <= 0):
        raise TerraError(f"{path}: field 'image_poses': expected rotations (orthonormal, det +1) in each pose")
    return pose


def recorded_visibility(ref: ReferenceFiles, cell_size: float, position: np.ndarray) -> VisibilityIndex | None:
    """The map's visibility index from Terra's terra_visibility.npy where the sidecar records it
    (None otherwise: it is rebuilt from the per-point image sets)."""
    from terra.npy import ArraySpec, read_npy

    count = ref.sidecar.get("visibility_pairs")
    path = ref.folder / rf.VISIBILITY
    if count is None:
        return None
    if not path.is_file():
        raise TerraError(f"{path}: missing ({rf.SIDECAR} records {count} visibility pairs in it)")
    m = ref.image_embedding.shape[0]
    spec = ArraySpec(("int64",), (int(count), 2), low=0, what="visibility cell key, image")
    pairs = read_npy(path, spec, what="visibility pairs")
    if pairs.size and pairs[:, 1].max() >= m:
        raise TerraError(f"{path}: image index {int(pairs[:, 1].max())} is past the {m} saved images")
    return VisibilityIndex.from_pairs(pairs[:, 0], pairs[:, 1], cell_size, position)


def image_positions(ref: ReferenceFiles) -> tuple[np.ndarray, dict[str, int]]:
    """(M, 3) estimated image positions (metres, map frame) and how many came from each source."""
    m = ref.image_embedding.shape[0]
    position = np.full((m, 3), np.nan)
    ranged = np.flatnonzero((ref.closest >= 0) & np.isfinite(ref.closest_distance))
    by_image = ref.closest[ranged]
    order = np.argsort(by_image, kind="stable")
    bounds = np.searchsorted(by_image[order], np.arange(m + 1))
    source = {"trilaterated": 0, "same_scan": 0, "centroid_of_seen_points": 0, "unknown": 0}
    for i in range(m):
        rows = ranged[order[bounds[i] : bounds[i + 1]]]
        if rows.size >= MIN_RANGES:
            rows = rows[np.unique(np.linspace(0, rows.size - 1, min(rows.size, MAX_RANGES)).astype(np.int64))]
            position[i] = _trilaterate(ref.points[rows].astype(np.float64), ref.closest_distance[rows])
            source["trilaterated"] += 1
    _fill_from_scan(ref, position, source)
    _fill_from_seen(ref, position, source)
    return position, source


def _fill_from_scan(ref: ReferenceFiles, position: np.ndarray, source: dict[str, int]) -> None:
    """Images without a position take the mean of the other cameras' positions of the same scan."""
    solved = ~np.isnan(position[:, 0])
    for stamp in np.unique(ref.image_stamp[~solved]):
        same = ref.image_stamp == stamp
        if (same & solved).any():
            missing = same & ~solved
            position[missing] = position[same & solved].mean(axis=0)
            source["same_scan"] += int(missing.sum())


def _fill_from_seen(ref: ReferenceFiles, position: np.ndarray, source: dict[str, int]) -> None:
    """Still missing: the centroid of the points the image saw (within range, or as closest)."""
    pairs = np.vstack(
        [ref.within_pairs, np.column_stack([np.flatnonzero(ref.closest >= 0), ref.closest[ref.closest >= 0]])]
    )
    centre = ref.points.mean(axis=0) if len(ref.points) else np.zeros(3)
    for i in np.flatnonzero(np.isnan(position[:, 0])):
        seen = pairs[pairs[:, 1] == i, 0]
        if seen.size:
            position[i] = ref.points[seen].mean(axis=0)
            source["centroid_of_seen_points"] += 1
        else:
            position[i] = centre
            source["unknown"] += 1


# ------------------------------------------------------------------------------ the bundle


def to_map(
    ref: ReferenceFiles, terrain_classes: list[str], embedder: str, cell_size: float, voxel_size: float
) -> tuple[MetricSemanticMap, dict[str, int]]:
    """The MetricSemanticMap of parsed reference files (see the module docstring)."""
    c = len(terrain_classes)
    if c == 0 or c >= ref.bank.shape[0]:
        raise TerraError(
            f"{ref.folder}: {c} terrain classes for a bank of {ref.bank.shape[0]} rows; the first C rows embed the "
            "C class names of the segmentation model, so give between 1 and K-1 classes"
        )
    counts = ref.counts.tocsc()
    votes = np.minimum(counts[:, :c].toarray(), np.iinfo(np.uint16).max).astype(np.uint16)
    objects = counts[:, c:].tocsr()
    objects.sort_indices()
    np.minimum(objects.data, np.iinfo(np.int32).max, out=objects.data)  # stored as int32, as votes as uint16
    pose = recorded_poses(ref)
    if pose is not None:
        position, source = pose[:, :3, 3], {"recorded": len(pose)}
    else:
        position, source = image_positions(ref)
        pose = np.tile(np.eye(4), (len(position), 1, 1))
        pose[:, :3, 3] = position
    names = ref.sidecar.get("camera_names") or []
    n_cameras = int(ref.image_camera.max()) + 1 if len(ref.image_camera) else 0
    if len(names) != n_cameras:
        names = [f"camera{n + 1}" for n in range(n_cameras)]
    images = ImageTable(
        stamp=ref.image_stamp,
        camera=ref.image_camera,
        T_map_cam=pose,
        embedding=rf.unit_rows(ref.image_embedding),
        camera_names=list(names),
    )
    visibility = recorded_visibility(ref, cell_size, position)
    if visibility is None:
        seen = np.flatnonzero(ref.closest >= 0)
        pairs = np.vstack([ref.within_pairs, np.column_stack([seen, ref.closest[seen]])])
        visibility = VisibilityIndex.from_pairs(
            voxel_keys(ref.points[pairs[:, 0]], cell_size), pairs[:, 1], cell_size, position
        )
    msm = MetricSemanticMap(
        points=ref.points,
        terrain_classes=list(terrain_classes),
        terrain_votes=votes,
        terrain_embeddings=rf.unit_rows(ref.bank[:c]),
        counts=objects.astype(np.int32),
        bank=rf.unit_rows(ref.bank[c:]),
        images=images,
        embedder=embedder,
        voxel_size=voxel_size,
        visibility=visibility,
    )
    return msm, source


def _write_bundle(out: Path, msm: MetricSemanticMap, ref: ReferenceFiles, source: dict[str, int]) -> None:
    """The map as bundle `out`, recording where it came from and how image positions were found."""
    from terra.mapping.storage import write_map

    config = {
        "import": {
            "format": "terra-reference",
            "folder": ref.folder.name,
            "itr": ref.itr,
            "image_range_m": ref.image_range,
            "pose_source": "image poses recorded by Terra's export"
            if "recorded" in source
            else "image positions estimated (see stats); orientation unknown",
        }
    }
    classes = [{"id": i, "name": n, "terrain": True} for i, n in enumerate(msm.terrain_classes)]
    stats = {f"image_position_{k}": v for k, v in source.items()}
    with BundleWriter(out) as writer:
        write_map(writer, msm, config=config, stats=stats, dataset=ref.folder.name, classes=classes)


def import_reference(
    folder: Path,
    out: Path,
    terrain_classes: list[str] | None = None,
    embedder: str | None = None,
    global_pc: Path | None = None,
    itr: int | None = None,
    overwrite: bool = False,
    cell_size: float = 2.0,
    voxel_size: float | None = None,
) -> ImportResult:
    """Turn reference output folder `folder` into the bundle `out` (written atomically)."""
    from terra.bundle import check_output_folder, is_bundle

    out = Path(out)
    check_output_folder(out, overwrite, "Terra bundle", is_bundle, "manifest.json")
    ref = read_reference(Path(folder), itr, global_pc)
    classes = list(terrain_classes or ref.sidecar.get("terrain_classes") or [])
    if not classes:
        raise TerraError(
            f"{folder}: the reference's files do not name the terrain classes; give them with --terrain-classes "
            "(the segmentation model's class names, in order, e.g. sidewalk,grass,asphalt)"
        )
    recorded = ref.sidecar.get("embedder") or {}
    name = embedder or recorded.get("name") or DEFAULT_EMBEDDER
    ref, unchecked = fit_embedder(ref, name)
    cell = float(ref.sidecar.get("visibility_cell_size") or cell_size)
    voxel = float(voxel_size or ref.sidecar.get("voxel_size") or 1.0)
    msm, source = to_map(ref, classes, name, cell, voxel)
    _write_bundle(out, msm, ref, source)
    return ImportResult(
        bundle=out,
        itr=int(ref.itr),
        points=len(msm),
        observed_points=int(np.count_nonzero(np.diff(msm.counts.indptr))),
        bank=int(msm.bank.shape[0]),
        images=len(msm.images),
        terrain_classes=classes,
        embedder=name,
        image_positions=dict(source),
        notes=[unchecked] if unchecked else [],
    )


def fit_embedder(ref: ReferenceFiles, name: str) -> tuple[ReferenceFiles, str | None]:
    """`ref` with its vectors cut to the dimension of embedder `name` (the sidecar's record, else the
    dimension of the embedder registered under the name) where the columns past it are zero padding;
    TerraError when the vectors do not fit that embedder. The second value says, where no embedder
    answers to `name` here, that the dimension went unchecked."""
    from dataclasses import replace

    from terra.perception.text import text_embedder_dim

    width = int(ref.bank.shape[1])
    recorded = (ref.sidecar.get("embedder") or {}).get("dim")
    known = text_embedder_dim(name)
    dim = int(recorded or known or width)
    if dim > width:
        raise TerraError(f"{ref.folder / rf.SIDECAR}: records {dim}-d vectors but the files hold {width} columns")
    if dim < width:
        tail = max(
            float(np.abs(ref.bank[:, dim:]).max(initial=0.0)),
            float(np.abs(ref.image_embedding[:, dim:]).max(initial=0.0)),
        )
        if tail != 0.0:
            raise _mismatch(ref, name, width, dim)
        ref = replace(ref, bank=ref.bank[:, :dim].copy(), image_embedding=ref.image_embedding[:, :dim].copy())
    if known is not None and known != dim:
        raise _mismatch(ref, name, dim, known)
    stored = ref.sidecar.get("stored_dim")
    if stored is not None and int(stored) != width:
        raise TerraError(f"{ref.folder / rf.SIDECAR}: records vectors {stored} wide but the files hold {width} columns")
    if known is None:
        return ref, (
            f"embedder {name!r} is not available here, so the {dim}-d vectors were not checked against it; "
            "`terra find` needs it registered (or import with --embedder naming one that is)"
        )
    return ref, None


def _mismatch(ref: ReferenceFiles, name: str, width: int, dim: int) -> TerraError:
    return TerraError(
        f"{ref.folder}: the files hold {width}-d vectors but embedder {name!r} gives {dim}-d ones; give --embedder "
        "the embedder the files were made with"
    )
