"""Where a new session lies in the map: T_map_session, found by registration (issue 26).

A session is a drive whose poses are in its own frame (T_session_lidar). Before its frames join a
map, its scans are accumulated into one cloud in the session frame (`session_cloud`) and registered
against the map's points, starting from a prior: the user's initial guess (x, y, yaw), or the
identity when both drives already share a frame. The refinement is small_gicp's GICP run coarse to
fine (correspondence distances of a few metres down to half a metre), single-threaded so the result
is the same on every run. The result is judged by our own nearest-neighbour distances, not by the
registration's cost: `overlap` is the fraction of the session's cloud within `overlap_distance` of
the map, `fitness` the fraction of those within `fit_distance`. An alignment that did not converge,
or whose overlap or fitness is below its floor, is refused (`check_alignment`) before anything is
merged.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial import cKDTree  # pyright: ignore[reportAttributeAccessIssue]  # stubless compiled scipy module

from terra.datasets.base import Dataset
from terra.errors import TerraError
from terra.geometry import make_pose, transform_points, voxel_keys, yaw_rotation


@dataclass(frozen=True)
class AlignSettings:
    """How a session is registered to a map (lengths in metres).

    voxel: both clouds are thinned to one point per voxel of this edge before registration.
    stages: GICP's maximum correspondence distance per stage, coarse to fine.
    overlap_distance / fit_distance: a session point within these of the map counts as overlapping
    / as fitting. min_overlap / min_fitness: the floors below which an alignment is refused.
    max_frames: scans read (evenly spread over the drive) to build the session's cloud.
    gnss_apart: a session whose GNSS prior puts it farther than this from the map's points, and whose
    registration from it fails, is of another site: refused without a search.
    """

    voxel: float = 0.4
    stages: tuple[float, ...] = (6.0, 3.0, 1.5, 0.75)
    iterations: int = 40
    overlap_distance: float = 1.0
    fit_distance: float = 0.3
    min_overlap: float = 0.3
    min_fitness: float = 0.8
    max_frames: int = 120
    gnss_apart: float = 1000.0


@dataclass(frozen=True)
class Alignment:
    """A registered session: T_map_session (4x4, map <- session), `how` it was found (its prior and
    the refinement), `overlap` and `fitness` (fractions, see the module docstring), `rmse` (metres,
    over the overlapping points), `converged` (the last GICP stage)."""

    T_map_session: np.ndarray
    how: str
    overlap: float
    fitness: float
    rmse: float
    converged: bool

    def to_json(self) -> dict[str, Any]:
        """The alignment as the manifest lists it beside the session."""
        return {
            "T_map_session": [[round(float(v), 9) for v in row] for row in self.T_map_session],
            "how": self.how,
            "overlap": round(float(self.overlap), 4),
            "fitness": round(float(self.fitness), 4),
            "rmse": round(float(self.rmse), 4),
        }


def pose_from_guess(x: float, y: float, yaw_deg: float) -> np.ndarray:
    """T_map_session (4x4) of a planar guess: the session origin at (x, y) metres in the map, its x axis
    turned `yaw_deg` degrees (counter-clockwise) from the map's."""
    return make_pose(yaw_rotation(np.radians(yaw_deg)), [x, y, 0.0])


def parse_guess(text: str) -> np.ndarray:
    """T_map_session of `--initial-guess x,y,yaw` (metres, metres, degrees); TerraError naming the option."""
    parts = [p.strip() for p in str(text).split(",")]
    try:
        values = [float(p) for p in parts]
    except ValueError:
        values = []
    if len(values) != 3 or not np.all(np.isfinite(values)):
        raise TerraError(f"--initial-guess {text!r}: expected x,y,yaw (metres, metres, degrees), e.g. 50,0,90")
    return pose_from_guess(*values)


def thin(points: np.ndarray, voxel: float) -> np.ndarray:
    """One point (the centroid) per occupied voxel of edge `voxel` metres; (M, 3) float64 in key order."""
    points = np.asarray(points, dtype=np.float64)[:, :3]
    if points.shape[0] == 0:
        return points
    keys, inverse = np.unique(voxel_keys(points, voxel), return_inverse=True)
    counts = np.bincount(inverse, minlength=keys.size).astype(np.float64)
    sums = np.stack([np.bincount(inverse, weights=points[:, a], minlength=keys.size) for a in range(3)], axis=1)
    return sums / counts[:, None]


def session_cloud(dataset: Dataset, voxel: float, max_frames: int) -> np.ndarray:
    """The session's scans in its own frame (T_session_lidar of each frame), thinned to `voxel` metres:
    (M, 3) float64. At most `max_frames` frames are read, evenly spread; unreadable frames or frames
    without a usable pose are left out (mapping counts them later)."""
    n = len(dataset)
    picks = np.unique(np.linspace(0, n - 1, min(n, max_frames)).round().astype(int)) if n else []
    clouds = []
    for i in picks:
        try:
            frame = dataset[int(i)]
        except TerraError:
            continue
        pose = np.asarray(frame.T_map_lidar, dtype=np.float64)
        points = np.asarray(frame.points, dtype=np.float64)
        if pose.shape != (4, 4) or not np.isfinite(pose).all() or points.ndim != 2 or points.shape[1] < 3:
            continue
        points = points[np.isfinite(points[:, :3]).all(axis=1), :3]
        clouds.append(thin(transform_points(pose, points), voxel))
    if not clouds:
        raise TerraError(f"dataset {dataset.name!r}: no usable scan to align the session with")
    return thin(np.concatenate(clouds), voxel)


def register(
    map_points: np.ndarray, session_points: np.ndarray, prior: np.ndarray, how: str, settings: AlignSettings
) -> Alignment:
    """Refine `prior` (T_map_session, 4x4) by GICP of `session_points` (session frame) onto `map_points`
    (map frame), both (N, 3) metres; the alignment with its overlap and fitness (not yet judged)."""
    try:
        import small_gicp
    except ImportError:
        raise TerraError(
            "joining a session needs the registration package small_gicp: pip install 'terra-3dsg[sessions]'"
        ) from None
    target, target_tree = small_gicp.preprocess_points(
        np.ascontiguousarray(map_points, dtype=np.float64), settings.voxel, num_threads=1
    )
    source, _ = small_gicp.preprocess_points(
        np.ascontiguousarray(session_points, dtype=np.float64), settings.voxel, num_threads=1
    )
    T = np.asarray(prior, dtype=np.float64)
    converged = False
    for distance in settings.stages:
        result = small_gicp.align(
            target,
            source,
            target_tree,
            init_T_target_source=T,
            registration_type="GICP",
            max_correspondence_distance=float(distance),
            num_threads=1,
            max_iterations=settings.iterations,
        )
        # A stage that starts at its optimum takes no step and reports no convergence: it has converged.
        T = np.asarray(result.T_target_source, dtype=np.float64)
        converged = bool(result.converged) or int(result.iterations) == 0
    T = np.round(T, 9)  # as the manifest lists it: a rerun from the manifest fuses the same poses
    overlap, fitness, rmse = judge(map_points, session_points, T, settings)
    return Alignment(T, f"{how} + GICP", overlap, fitness, rmse, converged)


def judge(
    map_points: np.ndarray, session_points: np.ndarray, T_map_session: np.ndarray, settings: AlignSettings
) -> tuple[float, float, float]:
    """(overlap, fitness, rmse in metres) of `session_points` placed by T_map_session against `map_points`,
    over the session's points that stand out of the ground (more than 0.5 m above the lowest point of their
    1 m cell) when it has 100 of them: flat ground fits anywhere on flat ground, structure does not."""
    session_points = np.asarray(session_points, dtype=np.float64)
    standing = _standing(session_points)
    if np.count_nonzero(standing) >= 100:
        session_points = session_points[standing]
    moved = transform_points(T_map_session, session_points)
    distance, _ = cKDTree(np.asarray(map_points, dtype=np.float64)).query(
        moved, k=1, distance_upper_bound=settings.overlap_distance
    )
    near = np.isfinite(distance)
    overlap = float(np.count_nonzero(near)) / max(moved.shape[0], 1)
    if not near.any():
        return overlap, 0.0, float("inf")
    fitness = float(np.count_nonzero(distance[near] <= settings.fit_distance)) / float(np.count_nonzero(near))
    return overlap, fitness, float(np.sqrt(np.mean(distance[near] ** 2)))


def _standing(points: np.ndarray, cell: float = 1.0, height: float = 0.5) -> np.ndarray:
    """(N,) points more than `height` metres above the lowest point of their `cell`-metre x-y cell."""
    _, inverse = np.unique(np.floor(points[:, :2] / cell).astype(np.int64), axis=0, return_inverse=True)
    inverse = inverse.ravel()
    low = np.full(int(inverse.max(initial=-1)) + 1, np.inf)
    np.minimum.at(low, inverse, points[:, 2])
    return points[:, 2] - low[inverse] > height


def search_priors(
    map_points: np.ndarray, session_points: np.ndarray, cell: float = 1.0, step_deg: float = 5.0, keep: int = 3
) -> list[np.ndarray]:
    """Candidate T_map_session (4x4, best first) when no guess is given: the x-y footprint of tall things
    (points of cells whose points span more than 1 m in height: walls, trees, cars) of the session, turned
    every `step_deg` degrees, cross-correlated with the map's at `cell` metres; per turn the best shift,
    then the `keep` best turns. The first is the exhaustive optimum of footprint overlap at `cell` metres.

    The map's image is transformed once; each turn only moves the session's tall points (found once, in
    its own frame) and transforms their image, padded to the map's so that every shift is a linear one."""
    from scipy import fft

    target, origin = _tall_image(_tall_points(np.asarray(map_points, np.float64), cell), cell)
    tall = _tall_points(np.asarray(session_points, np.float64), cell)
    if target.size == 0 or len(tall) == 0:
        return []
    side = int(np.ceil(np.linalg.norm(np.ptp(tall, axis=0)) / cell)) + 1  # any turn fits in side x side cells
    shape = tuple(fft.next_fast_len(n + side - 1, real=True) for n in target.shape)
    target_f = np.asarray(fft.rfft2(target, shape, workers=1))
    scored = []
    for yaw in np.arange(0.0, 360.0, step_deg):
        turned = tall @ yaw_rotation(np.radians(yaw))[:2, :2].T
        source, source_origin = _tall_image(turned, cell, (side, side))
        # Convolution with the flipped source is the correlation; the full linear result fits in `shape`.
        source_f = np.asarray(fft.rfft2(source[::-1, ::-1], shape, workers=1))
        score = np.asarray(fft.irfft2(target_f * source_f, shape, workers=1))
        row, col = np.unravel_index(int(np.argmax(score)), score.shape)
        shift = (np.array([col, row]) - (side - 1)) * cell + origin - source_origin
        scored.append((-round(float(score[row, col]), 6), float(yaw), float(shift[0]), float(shift[1])))
    scored.sort()
    return [pose_from_guess(x, y, yaw) for _, yaw, x, y in scored[:keep]]


def _tall_points(points: np.ndarray, cell: float) -> np.ndarray:
    """(T, 2) x-y metres: one per occupied quarter-`cell` square among the points of `cell`-metre cells
    whose points span more than 1 m in z."""
    _, inverse = np.unique(np.floor(points[:, :2] / cell).astype(np.int64), axis=0, return_inverse=True)
    inverse = inverse.ravel()
    top = np.full(int(inverse.max(initial=-1)) + 1, -np.inf)
    low = np.full(top.shape, np.inf)
    np.maximum.at(top, inverse, points[:, 2])
    np.minimum.at(low, inverse, points[:, 2])
    tall = points[(top - low)[inverse] > 1.0, :2]
    fine = np.unique(np.floor(tall / (cell / 4)).astype(np.int64), axis=0)
    return (fine + 0.5) * (cell / 4)


def _tall_image(xy: np.ndarray, cell: float, shape: tuple[int, int] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(rows y, cols x) image, 1.0 where a cell holds a point of `xy` (T, 2) metres, and its origin (2,)
    metres; `shape` (rows, cols) when given, else just large enough."""
    if len(xy) == 0:
        return np.zeros((0, 0)), np.zeros(2)
    origin = np.floor(xy.min(axis=0) / cell) * cell
    ij = np.floor((xy - origin) / cell).astype(np.int64)
    rows, cols = shape if shape is not None else (int(ij[:, 1].max()) + 1, int(ij[:, 0].max()) + 1)
    image = np.zeros((rows, cols))
    image[np.minimum(ij[:, 1], rows - 1), np.minimum(ij[:, 0], cols - 1)] = 1.0
    return image, origin


def trusted(alignment: Alignment, settings: AlignSettings) -> bool:
    """Whether the registration converged with overlap and fitness at least the settings' floors."""
    return (
        alignment.converged and alignment.overlap >= settings.min_overlap and alignment.fitness >= settings.min_fitness
    )


def check_alignment(alignment: Alignment, settings: AlignSettings, what: str) -> None:
    """TerraError (one line with the fitness and overlap; nothing merged) for an alignment not to trust."""
    if not trusted(alignment, settings):
        converged = "converged" if alignment.converged else "did not converge"
        raise TerraError(
            f"{what}: cannot align the session to the map: fitness {alignment.fitness:.2f} (at least "
            f"{settings.min_fitness}), overlap {alignment.overlap:.2f} (at least {settings.min_overlap}), the "
            f"registration from the {alignment.how} {converged}; nothing merged: give --initial-guess x,y,yaw "
            "(where the session's frame lies in the map)"
        )
