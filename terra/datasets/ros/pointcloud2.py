"""sensor_msgs/PointCloud2 -> NumPy arrays, vectorized from the message's own field layout.

The layout is whatever the driver wrote: each point is `point_step` bytes holding named fields at
byte `offset`s (datatype 1..8 = int8, uint8, int16, uint16, int32, uint32, float32, float64), rows
of `row_step` bytes (possibly padded past width * point_step), `height` rows (1 = unorganized),
little or big endian (`is_bigendian`). Per-point time: Ouster's `t` (uint32 nanoseconds since the
header stamp) or Velodyne's `time` (float32 seconds relative to the header stamp).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from terra.datasets.ros.bag import message_bytes
from terra.errors import TerraError

# PointField.datatype -> NumPy kind and size (sensor_msgs/PointField constants INT8=1 .. FLOAT64=8).
DATATYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
TIME_FIELDS = {"t": 1e-9, "time": 1.0}  # field name -> seconds per unit
LABEL_FIELDS = ("label", "instance")  # optional per-point class and instance ids (simulated or labelled clouds)


@dataclass
class DecodedCloud:
    """One scan: points (N, 3) float32 metres in the cloud's frame; intensity (N,) float32 or None;
    times (N,) float64 seconds relative to the header stamp, or None; labels / instances (N,)
    int32 when the cloud carries `label` / `instance` fields. Points with a NaN coordinate are dropped,
    and so are points at exactly (0, 0, 0), which organized clouds (Ouster) use for "no return"."""

    points: np.ndarray
    intensity: np.ndarray | None = None
    times: np.ndarray | None = None
    labels: np.ndarray | None = None
    instances: np.ndarray | None = None


def cloud_dtype(fields, point_step: int, big_endian: bool, names: list[str], where: str = "PointCloud2") -> np.dtype:
    """Structured dtype (itemsize `point_step`) holding the named fields at their offsets."""
    order = ">" if big_endian else "<"
    by_name = {f.name: f for f in fields}
    spec_names, formats, offsets = [], [], []
    for name in names:
        field = by_name[name]
        kind = DATATYPES.get(int(field.datatype))
        if kind is None:
            raise TerraError(
                f"{where}: field '{name}' has datatype {int(field.datatype)}; "
                "supported: 1..8 (int8, uint8, int16, uint16, int32, uint32, float32, float64)"
            )
        if int(field.count) != 1:
            raise TerraError(f"{where}: field '{name}' has count {int(field.count)}; expected 1 value per point")
        size = int(kind[1])
        if int(field.offset) + size > point_step:
            raise TerraError(
                f"{where}: field '{name}' at offset {int(field.offset)} ({size} bytes) "
                f"runs past point_step {point_step}"
            )
        spec_names.append(name)
        formats.append(order + kind)
        offsets.append(int(field.offset))
    return np.dtype({"names": spec_names, "formats": formats, "offsets": offsets, "itemsize": point_step})


def decode_pointcloud2(msg, where: str = "PointCloud2") -> DecodedCloud:
    """Decode a PointCloud2 message (any object with the message's attributes: height, width,
    fields [name, offset, datatype, count], is_bigendian, point_step, row_step, data).

    TerraError naming the field when the layout is unsupported (no x/y/z, unknown datatype,
    fields past point_step, data shorter than row_step * height)."""
    height, width = int(msg.height), int(msg.width)
    point_step, row_step = int(msg.point_step), int(msg.row_step)
    names = {f.name for f in msg.fields}
    missing = [n for n in ("x", "y", "z") if n not in names]
    if missing:
        have = ", ".join(sorted(names)) or "none"
        raise TerraError(f"{where}: no field '{missing[0]}' (fields: {have}); expected x, y, z")
    if point_step <= 0 or row_step < width * point_step:
        raise TerraError(f"{where}: row_step {row_step} is less than width {width} x point_step {point_step}")
    data = message_bytes(msg.data, where)
    if data.size < row_step * height:
        raise TerraError(f"{where}: data has {data.size} bytes, expected row_step {row_step} x height {height}")
    wanted = ["x", "y", "z"] + [n for n in ("intensity", *TIME_FIELDS, *LABEL_FIELDS) if n in names]
    time_name = next((n for n in TIME_FIELDS if n in names), None)
    dtype = cloud_dtype(msg.fields, point_step, bool(msg.is_bigendian), wanted, where)
    rows = data[: row_step * height].reshape(height, row_step)[:, : width * point_step]
    if row_step != width * point_step:
        rows = np.ascontiguousarray(rows)  # drop the row padding so the rows form one point array
    cloud = rows.reshape(-1).view(dtype)
    x, y, z = cloud["x"], cloud["y"], cloud["z"]
    # One-dimensional tests on the strided columns are several times faster than on an (N, 3) copy.
    invalid = np.isnan(x) | np.isnan(y) | np.isnan(z) | ((x == 0) & (y == 0) & (z == 0))
    idx = np.flatnonzero(~invalid)
    xyz = np.empty((idx.size, 3), np.float32)
    xyz[:, 0], xyz[:, 1], xyz[:, 2] = x[idx], y[idx], z[idx]

    def column(name: str, dtype) -> np.ndarray:
        return np.asarray(cloud[name][idx], dtype=dtype)

    return DecodedCloud(
        xyz,
        column("intensity", np.float32) if "intensity" in names else None,
        column(time_name, np.float64) * TIME_FIELDS[time_name] if time_name else None,
        column("label", np.int32) if "label" in names else None,
        column("instance", np.int32) if "instance" in names else None,
    )
