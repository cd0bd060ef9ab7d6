"""Sessions of one map: visits of the same site, each a drive in its own frame (issue 26).

The first drive mapped defines the map frame (session 1). `terra map MORE --append` adds frames to the
last session (its poses already in the map frame); `terra map SESSION --into MAP` starts a new session:
its drive is registered to the map (terra/mapping/align.py), its frames are fused with
T_map_lidar = T_map_session @ T_session_lidar, and its LiDAR returns are counted apart
(`map/state/session_hits`), so change detection knows what each visit observed.

The manifest keeps the sessions inside `components.map.sources`: a source that opened a session carries
`session` (1-based) and its alignment (`T_map_session`, `how`, `overlap`, `fitness`, `rmse`);
`session_list` groups the sources back into sessions.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from terra.bundle import Bundle
from terra.datasets.base import Dataset, Frame
from terra.errors import TerraError
from terra.geometry import invert_pose
from terra.npy import ArraySpec

if TYPE_CHECKING:  # `terra info` lists sessions without loading the registration code
    from terra.mapping.align import Alignment, AlignSettings

MAP_FRAME = "defines the map frame"


class SessionFrames:
    """`dataset` with every pose moved into the map frame: T_map_lidar = T_map_session @ T_session_lidar.
    The frames' content (points, images, stamps) is the source's own, so its fingerprint is too."""

    def __init__(self, dataset: Dataset, T_map_session: np.ndarray):
        self.source = dataset
        self.name = dataset.name
        self.classes = dataset.classes
        self.T_map_session = np.asarray(T_map_session, dtype=np.float64)

    def __len__(self) -> int:
        return len(self.source)

    def __getitem__(self, index: int) -> Frame:
        frame = self.source[index]  # a copy is moved: the loader may cache its frames
        return replace(frame, T_map_lidar=self.T_map_session @ np.asarray(frame.T_map_lidar, dtype=np.float64))

    def global_map(self) -> np.ndarray | None:
        return None  # a joined session fuses into the map's own points


def session_list(sources: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The map's sessions from its sources: per session its index (1-based), name and fingerprint (of the
    source that opened it), first frame, frames, time span (s), T_map_session (4x4 rows), how it was found
    and its fit (overlap, fitness, rmse; None for the first session)."""
    sessions: list[dict[str, Any]] = []
    for source in sources:
        if not isinstance(source, dict):
            continue
        span = source.get("time_span")
        if not sessions or source.get("session") is not None:
            sessions.append(
                {
                    "session": len(sessions) + 1,
                    "name": source.get("name"),
                    "fingerprint": source.get("fingerprint"),
                    "first_frame": source.get("first_frame", 0),
                    "frames": 0,
                    "time_span": None,
                    "T_map_session": source.get("T_map_session", np.eye(4).tolist()),
                    "how": source.get("how", MAP_FRAME),
                    **{k: source.get(k) for k in ("overlap", "fitness", "rmse")},
                }
            )
        session = sessions[-1]
        session["frames"] += int(source.get("frames") or 0)
        if isinstance(span, list) and len(span) == 2:
            old = session["time_span"]
            session["time_span"] = list(span) if old is None else [min(old[0], span[0]), max(old[1], span[1])]
    return sessions


@dataclass
class JoinPlan:
    """What `plan_join` found: the alignment (judged good) and the session's frames in the map frame."""

    alignment: Alignment
    frames: SessionFrames


def plan_join(dataset: Dataset, out: Path, prior: np.ndarray | None, settings: AlignSettings | None = None) -> JoinPlan:
    """Align `dataset` (a drive in its own frame) to the map in the bundle `out`, from `prior`
    (T_map_session, 4x4: the user's initial guess) or, without one, from both drives' GNSS anchors when
    the map and the session have them, else the identity (both drives share a frame) and a search
    (`find_alignment`). TerraError, one line and nothing written, for a bundle
    that cannot take a session, a source already in the map, or an alignment that did not converge or
    overlaps too little."""
    from terra.datasets.fingerprint import dataset_fingerprint
    from terra.mapping.align import AlignSettings, session_cloud
    from terra.mapping.state import append_base, state_meta

    settings = settings or AlignSettings()
    base = append_base(Path(out))
    if state_meta(base)["geometry"] != "voxel":
        raise TerraError(
            f"{base.path}: the map is fused on its dataset's own global map, where another drive's points have no "
            "place; map the first session with mapping.fusion.use_global_map: false to join others to it"
        )
    _check_classes(base, dataset)
    fingerprint = dataset_fingerprint(dataset)
    for old in (base.model.components.map.sources or []) if base.model.components.map else []:
        if isinstance(old, dict) and old.get("fingerprint") == fingerprint:
            raise TerraError(
                f"{dataset.name}: this session is already in the map (same content as {str(old.get('name')):.200}); "
                "nothing merged"
            )
    cloud = session_cloud(dataset, settings.voxel, settings.max_frames)
    gnss = gnss_prior(base, dataset) if prior is None else None
    alignment = find_alignment(map_points(base), cloud, prior, settings, str(dataset.name), gnss)
    return JoinPlan(alignment, SessionFrames(dataset, alignment.T_map_session))


def find_alignment(
    map_cloud: np.ndarray,
    cloud: np.ndarray,
    prior: np.ndarray | None,
    settings: AlignSettings,
    what: str,
    gnss: np.ndarray | None = None,
) -> Alignment:
    """The alignment of `cloud` (session frame) to `map_cloud`, in this order of evidence:
    - from `prior` (T_map_session, the user's guess) when given;
    - else from `gnss` (T_map_session of both frames' GNSS anchors) when given and its refinement
      passes the floors; when it does not and GNSS puts the session far from the map (another site),
      TerraError without a search;
    - else the best (overlap x fitness) of the refinements from the shared frame (identity, where it
      already overlaps the map), from the GNSS prior, and from the candidates of a search over turns and
      shifts of the tall things' footprints (`search_priors`): a repetitive site (rows of parked cars)
      has wrong fits that pass the floors, which the right one beats.
    TerraError naming its fitness and overlap when the one chosen does not pass `check_alignment`."""
    from terra.mapping.align import check_alignment, judge, register, search_priors, trusted

    if prior is not None:
        alignment = register(map_cloud, cloud, np.asarray(prior, dtype=np.float64), "initial guess", settings)
        check_alignment(alignment, settings, what)
        return alignment
    tried = []
    if gnss is not None:
        tried.append(register(map_cloud, cloud, np.asarray(gnss, dtype=np.float64), "GNSS prior", settings))
        if trusted(tried[0], settings):
            return tried[0]
        _refuse_another_site(map_cloud, cloud, np.asarray(gnss, dtype=np.float64), settings, what)
    starts = [("place search", T) for T in search_priors(map_cloud, cloud)]
    # The shared frame is tried only where it already overlaps the map: from far off, GICP spends its
    # every iteration on a pose the search has already beaten.
    if not starts or judge(map_cloud, cloud, np.eye(4), settings)[0] >= settings.min_overlap:
        starts.insert(0, ("shared frame", np.eye(4)))
    tried += [register(map_cloud, cloud, start, how, settings) for how, start in starts]
    alignment = max(tried, key=lambda a: (a.converged, a.overlap * a.fitness))
    check_alignment(alignment, settings, what)
    return alignment


def _refuse_another_site(
    map_cloud: np.ndarray, cloud: np.ndarray, gnss: np.ndarray, settings: AlignSettings, what: str
) -> None:
    """TerraError (one line, nothing merged) when the GNSS prior puts the session's centre farther than
    `settings.gnss_apart` metres from the map's points' x-y bounding box: another site, not a prior a
    search could correct."""
    from terra.geometry import transform_points

    centre = transform_points(gnss, np.asarray(cloud, np.float64).mean(axis=0, keepdims=True))[0, :2]
    low, high = map_cloud[:, :2].min(axis=0), map_cloud[:, :2].max(axis=0)
    apart = float(np.linalg.norm(np.maximum(np.maximum(low - centre, centre - high), 0.0)))
    if apart > settings.gnss_apart:
        raise TerraError(
            f"{what}: by GNSS the session lies {apart / 1000:.1f} km from the map: a drive of another site; "
            "nothing merged (give --initial-guess x,y,yaw if its GNSS is wrong)"
        )


def gnss_prior(base: Bundle, dataset: Dataset) -> np.ndarray | None:
    """T_map_session from the map's WGS84 anchor and the session's (both fitted to GNSS fixes, or a
    KITTI drive's OXTS), or None when either is unknown."""
    from terra.datasets.base import GeoreferencedDataset
    from terra.mapping.state import wgs84_anchor
    from terra.schemas import Wgs84Anchor
    from terra.wgs84 import pose_between

    on_map = wgs84_anchor(base)
    own = dataset.wgs84_anchor() if isinstance(dataset, GeoreferencedDataset) else None
    if on_map is None or own is None:
        return None
    return pose_between(Wgs84Anchor.model_validate(on_map), Wgs84Anchor.model_validate(own))


def _check_classes(base: Bundle, dataset: Dataset) -> None:
    """A session labelled with another class table (another site's or another sensor setup's) is refused."""
    from terra.schemas import MapMeta

    recorded = [row.model_dump() for row in base.document("map/meta.json", MapMeta).classes]
    if recorded and recorded != dataset.classes.to_json():
        raise TerraError(
            f"{dataset.name}: its class table differs from the map's ({base.path}/map/meta.json); "
            "a session must be labelled with the map's classes"
        )


def map_points(base: Bundle) -> np.ndarray:
    """The stored map's points (N, 3) float32, metres, map frame."""
    from terra.mapping.chunks import is_chunked, stored_rows

    info = base.model.components.map
    n = int(info.points or 0) if info is not None else 0
    if is_chunked(base) and info is not None:  # a live version (terra/mapping/chunks.py)
        return stored_rows(base, ("points",), n, int(info.bank or 0), len(base.model.terrain_classes))["points"]
    return base.array("map/points", ArraySpec(("float32",), (n, 3), finite=True, what="x, y, z metres"))


def relative_error(T_true: np.ndarray, T_found: np.ndarray) -> tuple[float, float]:
    """(translation metres, rotation degrees) of T_found against T_true (both map <- session)."""
    error = invert_pose(np.asarray(T_true, np.float64)) @ np.asarray(T_found, np.float64)
    cos = np.clip((np.trace(error[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.linalg.norm(error[:3, 3])), float(np.degrees(np.arccos(cos)))
