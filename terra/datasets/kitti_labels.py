"""KITTI object and tracking labels as oriented 3D boxes (the devkits' `readme.txt` formats).

Object labels (`label_2/NNNNNN.txt`, one file per frame) hold 15 fields per line, 16 with a score:
type, truncated, occluded, alpha, bbox left top right bottom (pixels), dimensions h w l (metres),
location x y z (metres), rotation_y (radians). Tracking labels (`label_02/NNNN.txt`, one file per
sequence) put frame and track id in front: 17 fields, 18 with a score.

Frames: the location is the centre of the box's bottom face in the rectified reference camera
(camera 0 after R_rect: x right, y down, z forward). The box is l long along its own x, w wide
along z, h high along -y, turned by rotation_y about the camera's y axis, so its length axis points
along (cos ry, 0, -sin ry). `DontCare` lines mark unlabelled areas and are skipped.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from terra.datasets.ground_truth import ObjectBox
from terra.errors import TerraError

OBJECT_FIELDS = 15
TRACKING_FIELDS = 17
IGNORED_TYPES = frozenset({"DontCare"})


@dataclass(frozen=True)
class KittiLabel:
    """One labelled object in one frame (rectified camera-0 coordinates, metres, radians)."""

    frame: int
    track: int | None
    type: str
    truncated: float
    occluded: int
    alpha: float
    bbox: tuple[float, float, float, float]
    dimensions: tuple[float, float, float]  # h, w, l
    location: tuple[float, float, float]  # bottom-face centre
    rotation_y: float

    @property
    def class_name(self) -> str:
        """The type as a plain name for text queries: 'Person_sitting' -> 'person sitting'."""
        return self.type.replace("_", " ").lower()


@dataclass
class OrientedBox:
    """A box in some frame: centre (3,), size (3,) = (length, width, height) metres, and `axes`
    (3, 3) whose columns are the unit length, width and height directions in that frame."""

    center: np.ndarray
    size: np.ndarray
    axes: np.ndarray

    def contains(self, points: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """(N,) whether each point (N, 3) lies inside the box grown by `margin` metres."""
        local = (np.asarray(points, np.float64) - self.center) @ self.axes
        return np.all(np.abs(local) <= self.size / 2 + margin, axis=1)

    def yaw(self) -> float:
        """Heading of the length axis about +z (radians), for gravity-aligned frames."""
        return float(np.arctan2(self.axes[1, 0], self.axes[0, 0]))


def parse_label_line(text: str, where: str, tracking: bool) -> KittiLabel | None:
    """One label line, or None for DontCare; TerraError naming `where` (file:line) otherwise."""
    words = text.split()
    count = TRACKING_FIELDS if tracking else OBJECT_FIELDS
    kind = "tracking" if tracking else "object"
    if len(words) not in (count, count + 1):
        raise TerraError(
            f"{where}: a KITTI {kind} label has {count} fields ({count + 1} with a score), got {len(words)}"
        )
    head = 2 if tracking else 0
    if words[head] in IGNORED_TYPES:
        return None
    try:
        numbers = [float(w) for w in words[head + 1 : head + 15]]
        frame, track = (int(words[0]), int(words[1])) if tracking else (-1, None)
    except ValueError:
        raise TerraError(
            f"{where}: expected numbers after the type {words[head]!r}, got {' '.join(words[head + 1 :])[:60]!r}"
        ) from None
    if not np.all(np.isfinite(numbers)):
        raise TerraError(f"{where}: non-finite number in the label")
    h, w, length = numbers[7:10]
    if min(h, w, length) <= 0:
        raise TerraError(f"{where}: dimensions h w l must be positive, got {h} {w} {length}")
    return KittiLabel(
        frame,
        track,
        words[head],
        numbers[0],
        int(numbers[1]),
        numbers[2],
        (numbers[3], numbers[4], numbers[5], numbers[6]),
        (h, w, length),
        (numbers[10], numbers[11], numbers[12]),
        numbers[13],
    )


def read_label_file(path: Path, tracking: bool, frame: int = -1) -> list[KittiLabel]:
    """Every labelled object of a file (DontCare skipped); object files get `frame` as their frame."""
    from terra.fileio import read_text

    lines = read_text(path, "KITTI label file").splitlines()
    out = []
    for number, line in enumerate(lines, start=1):
        if line.strip():
            label = parse_label_line(line, f"{path}:{number}", tracking)
            if label is not None:
                out.append(label if tracking else _with_frame(label, frame))
    return out


def _with_frame(label: KittiLabel, frame: int) -> KittiLabel:
    from dataclasses import replace

    return replace(label, frame=frame)


def box_in_frame(label: KittiLabel, T_target_rect: np.ndarray) -> OrientedBox:
    """The label's box in a target frame (LiDAR, map) from T_target_rect (4x4, rectified camera 0
    -> target, metres)."""
    h, w, length = label.dimensions
    ry = label.rotation_y
    c, s = np.cos(ry), np.sin(ry)
    axes_rect = np.array([[c, 0.0, s], [0.0, -1.0, 0.0], [-s, 0.0, c]])  # columns: length, height (up), width
    axes_rect = axes_rect[:, [0, 2, 1]]  # length, width, height
    center_rect = np.asarray(label.location, np.float64) + np.array([0.0, -h / 2.0, 0.0])
    R, t = T_target_rect[:3, :3], T_target_rect[:3, 3]
    return OrientedBox(R @ center_rect + t, np.array([length, w, h]), R @ axes_rect)


def rotation_y_of(heading_rect: np.ndarray) -> float:
    """rotation_y of a length axis given in rectified camera coordinates (its y part is dropped)."""
    return float(np.arctan2(-heading_rect[2], heading_rect[0]))


def objects_from_labels(
    boxes: list[tuple[KittiLabel, OrientedBox]], merge_radius: float = 1.0, moving_spread: float = 1.0
) -> tuple[list[ObjectBox], dict[str, int]]:
    """One map-frame ObjectBox per physical object seen in several frames.

    `boxes` pairs each label with its box in the map frame. Tracking labels group by track id;
    object labels (no ids) group greedily by type and centre distance below `merge_radius` metres.
    A group's box is the median centre and size and the mean heading (modulo pi: a box looks the
    same turned half a turn). Groups whose centres spread more than `moving_spread` metres from
    their median moved while labelled: a static map cannot hold them, so they are left out and
    counted. Returns the objects (ordered by first sighting) and the counts left out by reason."""
    groups = _group(boxes, merge_radius)
    objects, left_out = [], {"moving": 0}
    for number, members in enumerate(groups, start=1):
        centers = np.array([b.center for _, b in members])
        center = np.median(centers, axis=0)
        if np.linalg.norm(centers - center, axis=1).max() > moving_spread:
            left_out["moving"] += 1
            continue
        doubled = np.array([2.0 * b.yaw() for _, b in members])
        yaw = 0.5 * float(np.arctan2(np.sin(doubled).mean(), np.cos(doubled).mean()))
        first = members[0][0]
        objects.append(
            ObjectBox(
                first.track if first.track is not None else number,
                -1,
                first.class_name,
                center,
                np.median([b.size for _, b in members], axis=0),
                yaw,
            )
        )
    return objects, left_out


def _group(
    boxes: list[tuple[KittiLabel, OrientedBox]], merge_radius: float
) -> list[list[tuple[KittiLabel, OrientedBox]]]:
    """Sightings of the same object: by (type, track id), or for untracked labels by type and
    distance to the running mean centre of a group (greedy, in the given order)."""
    groups: list[list[tuple[KittiLabel, OrientedBox]]] = []
    by_track: dict[tuple[str, int], int] = {}
    untracked: dict[str, tuple[list[int], list[np.ndarray]]] = {}  # type -> group numbers, centre sums
    for label, box in boxes:
        if label.track is not None:
            key = (label.type, label.track)
            if key not in by_track:
                by_track[key] = len(groups)
                groups.append([])
            groups[by_track[key]].append((label, box))
            continue
        numbers, sums = untracked.setdefault(label.type, ([], []))
        if numbers:
            means = np.array([total / len(groups[g]) for g, total in zip(numbers, sums)])
            distance = np.linalg.norm(means - box.center, axis=1)
            best = int(np.argmin(distance))
            if distance[best] < merge_radius:
                groups[numbers[best]].append((label, box))
                sums[best] = sums[best] + box.center
                continue
        numbers.append(len(groups))
        sums.append(np.array(box.center, dtype=np.float64))
        groups.append([(label, box)])
    return groups


# ----------------------------------------------------------------------------- labels of a drive
def label_files(drive: Path) -> list[Path]:
    """A drive's label files: its tracking file (`label_02/NNNN.txt`: the only one, or the one
    numbered like the drive) or its per-frame object files (`label_2/*.txt`); [] when it has none."""
    drive = Path(drive)
    tracking = sorted((drive / "label_02").glob("*.txt")) if (drive / "label_02").is_dir() else []
    objects = sorted((drive / "label_2").glob("*.txt")) if (drive / "label_2").is_dir() else []
    if tracking and objects:
        raise TerraError(f"{drive}: has both label_02/ (tracking) and label_2/ (object) labels; keep one of them")
    if len(tracking) > 1:
        number = drive.name.split("_drive_")[-1][:4]
        named = [p for p in tracking if p.stem == number]
        if not named:
            raise TerraError(
                f"{drive / 'label_02'}: {len(tracking)} tracking files and none named {number}.txt after the drive"
            )
        tracking = named
    return tracking or objects


def read_drive_labels(drive: Path) -> list[KittiLabel]:
    """Every label of a drive; `frame` is the drive's file index (NNNNNNNNNN of its scans)."""
    files = label_files(drive)
    if files and files[0].parent.name == "label_02":
        return read_label_file(files[0], tracking=True)
    out = []
    for path in files:
        if not path.stem.isdigit():
            raise TerraError(f"{path}: object label files are named by frame index, e.g. 0000000042.txt")
        out += read_label_file(path, tracking=False, frame=int(path.stem))
    return out


def ground_truth_from_labels(
    labels: list[KittiLabel],
    T_map_rect: dict[int, np.ndarray],
    source: str,
    merge_radius: float = 1.0,
    moving_spread: float = 1.0,
):
    """Ground truth (objects only) in the map frame from labels and, per frame index, T_map_rect
    (rectified camera 0 -> map). Labels of frames without a pose are left out and counted."""
    from terra.datasets.ground_truth import GroundTruth

    boxes = [(label, box_in_frame(label, T_map_rect[label.frame])) for label in labels if label.frame in T_map_rect]
    objects, left_out = objects_from_labels(boxes, merge_radius, moving_spread)
    notes = [f"{source}: KITTI labels hold objects only; terrain and named regions are not labelled"]
    if left_out["moving"]:
        notes.append(
            f"{left_out['moving']} objects moved while labelled (centres spread over {moving_spread} m) "
            "and are left out"
        )
    if len(boxes) < len(labels):
        notes.append(f"{len(labels) - len(boxes)} labels belong to frames without a pose and are left out")
    return GroundTruth(objects, None, [], notes)
