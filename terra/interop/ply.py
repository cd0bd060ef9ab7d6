"""The map's points as a binary PLY file (CloudCompare, Open3D, MeshLab, trimesh read it).

Per vertex: x, y, z (float32, metres, map frame), red, green, blue (uchar), terrain (int32: index
into the terrain classes listed in the header comments, -1 none) and ms_max (int32: the bank entry
observed most often at the point, -1 none). The colour follows `color`: "terrain" uses Terra's
terrain palette (points without terrain dark grey); "ms-max" gives each bank entry a colour of a
qualitative palette (unobserved points light grey).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import numpy as np

from terra import __version__
from terra.bundle import Bundle
from terra.errors import TerraError
from terra.interop.output import write_file
from terra.mapping.semantic_map import MetricSemanticMap

PlyColour = Literal["terrain", "ms-max"]
PLY_COLOURS = ("terrain", "ms-max")
UNOBSERVED_GREY = (0.8, 0.8, 0.8)


def bank_colours(count: int) -> np.ndarray:
    """(count, 3) RGB in 0..1 per bank entry: a fixed shuffle of a qualitative palette."""
    from terra.viz.places import region_colours

    return region_colours(np.arange(max(count, 1)), seed=7)[:count]


def point_colours(msm: MetricSemanticMap, color: str) -> np.ndarray:
    """(N, 3) RGB in 0..1 of every map point by terrain or by MS-Max bank entry."""
    from terra.viz.style import terrain_palette

    if color == "terrain":
        return terrain_palette(msm.terrain_classes)[msm.terrain_index()]
    if color == "ms-max":
        ids = msm.ms_max_ids()
        palette = np.vstack([bank_colours(msm.bank.shape[0]), [UNOBSERVED_GREY]])
        return palette[ids]  # -1 picks the last row
    raise TerraError(f"--color {color!r}: expected one of {', '.join(PLY_COLOURS)}")


def ply_bytes(
    points: np.ndarray, rgb: np.ndarray, terrain: np.ndarray, ms_max: np.ndarray, comments: list[str]
) -> bytes:
    """A binary little-endian PLY of N vertices (see the module docstring)."""
    n = int(points.shape[0])
    vertex = np.zeros(
        n,
        dtype=[
            ("x", "<f4"),
            ("y", "<f4"),
            ("z", "<f4"),
            ("red", "u1"),
            ("green", "u1"),
            ("blue", "u1"),
            ("terrain", "<i4"),
            ("ms_max", "<i4"),
        ],
    )
    for axis, name in enumerate("xyz"):
        vertex[name] = points[:, axis]
    rgb8 = np.clip(np.round(np.asarray(rgb) * 255), 0, 255).astype(np.uint8)
    vertex["red"], vertex["green"], vertex["blue"] = rgb8[:, 0], rgb8[:, 1], rgb8[:, 2]
    vertex["terrain"], vertex["ms_max"] = terrain, ms_max
    header = [
        "ply",
        "format binary_little_endian 1.0",
        *(f"comment {c}" for c in comments),
        f"element vertex {n}",
        "property float x",
        "property float y",
        "property float z",
        "property uchar red",
        "property uchar green",
        "property uchar blue",
        "property int terrain",
        "property int ms_max",
        "end_header",
    ]
    return ("\n".join(header) + "\n").encode("ascii") + vertex.tobytes()


def export_ply(bundle: Bundle, out: Path, overwrite: bool = False, color: str = "terrain") -> dict[str, Any]:
    """Write the bundle's map points to `out` as PLY coloured by `color`; returns a summary."""
    from terra.mapping.storage import load_map

    if color not in PLY_COLOURS:
        raise TerraError(f"--color {color!r}: expected one of {', '.join(PLY_COLOURS)}")
    msm = load_map(bundle)
    comments = [
        f"written by terra {__version__}",
        "frame map, metres",
        f"colour {color}",
        *(f"terrain {i} {name}" for i, name in enumerate(msm.terrain_classes)),
        "terrain -1 none; ms_max = most observed bank entry, -1 none",
    ]
    data = ply_bytes(msm.points, point_colours(msm, color), msm.terrain_index(), msm.ms_max_ids(), comments)
    write_file(out, data, overwrite)
    return {"format": "ply", "out": str(out), "points": len(msm), "color": color}
