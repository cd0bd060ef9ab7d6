"""What the viewer draws, as plain arrays (metres, map frame; colours uint8 RGB): no viser here.

Large maps stay responsive by drawing a fixed, seeded subset of the points (`display_subset`);
every query still runs on the whole map.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from terra.graph.scene_graph import SceneGraph
from terra.mapping.semantic_map import MetricSemanticMap

UNOBSERVED = np.array([150, 150, 150], dtype=np.uint8)
REGION_LIFT = 6.0  # metres between drawn region levels above the places


def display_subset(count: int, max_points: int, seed: int = 0) -> np.ndarray:
    """Sorted indices of at most `max_points` of `count` points, the same every time (for drawing
    only)."""
    if count <= max_points:
        return np.arange(count)
    return np.sort(np.random.default_rng(seed).permutation(count)[:max_points])


def to_uint8(rgb: np.ndarray) -> np.ndarray:
    return np.clip(np.round(np.asarray(rgb) * 255), 0, 255).astype(np.uint8)


def terrain_point_colours(msm: MetricSemanticMap, rows: np.ndarray) -> np.ndarray:
    """(n, 3) uint8 terrain colour of map points `rows` (Terra's palette; no terrain: dark grey)."""
    from terra.viz.style import terrain_palette

    return to_uint8(terrain_palette(msm.terrain_classes)[msm.terrain_index()[rows]])


def bank_classes(bank: np.ndarray, class_vectors: np.ndarray) -> np.ndarray:
    """(K,) index of the class name (rows of class_vectors, unit) nearest to each bank entry."""
    if len(class_vectors) == 0 or len(bank) == 0:
        return np.zeros(len(bank), dtype=np.int64)
    return np.argmax(bank @ class_vectors.T, axis=1)


def class_palette(count: int) -> np.ndarray:
    """(count, 3) uint8 colours, a fixed shuffle of a qualitative palette."""
    from terra.viz.places import region_colours

    return to_uint8(region_colours(np.arange(max(count, 1)), seed=3)[:count])


def class_point_colours(max_ids: np.ndarray, class_of_bank: np.ndarray, palette: np.ndarray) -> np.ndarray:
    """(n, 3) uint8: each point's MS-Max bank entry through its class to a colour (-1: grey)."""
    out = np.tile(UNOBSERVED, (len(max_ids), 1))
    seen = max_ids >= 0
    out[seen] = palette[class_of_bank[max_ids[seen]]]
    return out


def similarity_colours(similarity: np.ndarray, observed: np.ndarray) -> tuple[np.ndarray, tuple[float, float]]:
    """(n, 3) uint8 viridis colours of cosines stretched over their observed range, unobserved
    points grey; and that range."""
    from matplotlib import colormaps

    out = np.tile(UNOBSERVED, (len(similarity), 1))
    if not observed.any():
        return out, (0.0, 0.0)
    lo, hi = float(similarity[observed].min()), float(similarity[observed].max())
    scaled = (similarity[observed] - lo) / max(hi - lo, 1e-6)
    out[observed] = to_uint8(colormaps["viridis"](scaled)[:, :3])
    return out, (lo, hi)


def place_colours(graph: SceneGraph) -> np.ndarray:
    from terra.viz.style import terrain_palette

    return to_uint8(terrain_palette(graph.terrain_classes)[graph.places.terrain])


def place_edge_segments(graph: SceneGraph, lift: float = 0.3) -> np.ndarray:
    """(E, 2, 3) place edge segments, lifted `lift` metres above the ground."""
    pos = graph.places.position + np.array([0.0, 0.0, lift])
    return pos[graph.place_edges].reshape(-1, 2, 3).astype(np.float32)


@dataclass
class RegionLayer:
    """One drawn region level: node positions (R, 3), colours (R, 3) uint8, and segments (C, 2, 3)
    from each region to its children (places for level 1, regions of the level below)."""

    level: int
    position: np.ndarray
    colours: np.ndarray
    segments: np.ndarray
    segment_colours: np.ndarray


def region_layers(graph: SceneGraph, lift: float = REGION_LIFT) -> list[RegionLayer]:
    """Every region level drawn `lift` metres above the one below it (places at their height)."""
    from terra.viz.places import region_colours

    top = float(graph.places.position[:, 2].max()) if len(graph.places) else 0.0
    below = graph.places.position
    layers = []
    for level in graph.regions:
        pos = level.position.copy()
        pos[:, 2] = top + lift * level.level
        colours = to_uint8(region_colours(np.arange(len(level)), seed=level.level))
        segments = np.stack([pos[level.parent_of_child], below], axis=1).astype(np.float32)
        layers.append(
            RegionLayer(
                level.level, pos, colours, segments, np.repeat(colours[level.parent_of_child][:, None], 2, axis=1)
            )
        )
        below = pos
    return layers


def yaw_wxyz(yaw: float) -> tuple[float, float, float, float]:
    """Quaternion (w, x, y, z) of a rotation of `yaw` radians about +z."""
    return (float(np.cos(yaw / 2)), 0.0, 0.0, float(np.sin(yaw / 2)))


def ray_place(graph: SceneGraph, origin: np.ndarray, direction: np.ndarray) -> int:
    """The place nearest (2-D) to where a view ray (map frame) meets the places' median ground
    height; -1 when the ray does not point down to it or there are no places."""
    if len(graph.places) == 0:
        return -1
    origin, direction = np.asarray(origin, float), np.asarray(direction, float)
    ground = float(np.median(graph.places.position[:, 2]))
    if abs(direction[2]) < 1e-9 or (ground - origin[2]) / direction[2] <= 0:
        return -1
    hit = origin + direction * (ground - origin[2]) / direction[2]
    return int(np.argmin(np.linalg.norm(graph.places.position[:, :2] - hit[:2], axis=1)))


def path_segments(waypoints: np.ndarray, lift: float = 0.6) -> np.ndarray:
    """(n - 1, 2, 3) segments of a path through `waypoints` (n, 3), lifted `lift` metres."""
    pos = np.asarray(waypoints, dtype=np.float32) + np.array([0.0, 0.0, lift], dtype=np.float32)
    return np.stack([pos[:-1], pos[1:]], axis=1)


TRAJECTORY_GAP = 30.0  # seconds between two images of one camera that end a drive (another session)


def trajectory_segments(msm: MetricSemanticMap, camera: int = 0, lift: float = 0.3) -> np.ndarray:
    """(k, 2, 3) segments joining the centres of camera `camera`'s consecutive images in the order they
    were fused (the drives so far), metres, map frame, lifted `lift` metres. A drive ends where the
    next image's stamp is not later or more than TRAJECTORY_GAP seconds later: each session of a joined
    map runs on its own clock, and a line from one drive's end to the next one's start is no path."""
    images = msm.images
    mine = np.flatnonzero(np.asarray(images.camera) == camera)
    if mine.size < 2:
        return np.zeros((0, 2, 3), dtype=np.float32)
    segments = path_segments(images.position[mine], lift)
    step = np.diff(np.asarray(images.stamp, dtype=np.float64)[mine])
    return segments[(step > 0) & (step <= TRAJECTORY_GAP)]


def parse_end(text: str) -> tuple[str, int | str | None]:
    """A start or goal as typed: "" -> ("default", None), "12" -> ("node", 12), other -> ("query", text)."""
    text = text.strip()
    if not text:
        return "default", None
    if text.isdigit():
        return "node", int(text)
    return "query", text


def terrain_list(text: str) -> list[str]:
    """Comma-separated terrain names, blanks dropped."""
    return [t.strip() for t in text.split(",") if t.strip()]
