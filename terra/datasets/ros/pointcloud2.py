"""sensor_msgs/PointCloud2 -> NumPy arrays, vectorized from the message's own field layout.

The layout is whatever the driver wrote: each point is `point_step` bytes holding named fields at
byte `offset`s (datatype 1..8 = int8, uint8, int16, uint16, int32, uint32, float32, float64), rows
of `row_step` bytes (possibly padded past width * point_step), `height` rows (1 = unorganized),
little or big endian (`is_bigendian`).

Per-point time, as drivers write it: Ouster's `t` (uint32 nanoseconds since the header stamp),
Velodyne's `time` (float32 seconds relative to the header stamp), Livox's `offset_time` (uint32
nanoseconds since the stamp), `timestamp` (absolute; Hesai and Robosense: float64 seconds, Livox:
float64 nanoseconds), and split into whole seconds and nanoseconds in two fields
(Luminar's `time_sec` + `time_nsec`, absolute). A time more than ABSOLUTE_AFTER seconds from zero
is a time since 1970, made relative to the header stamp (split fields in integers, so no
nanosecond is lost); the decoded times are always seconds relative to the stamp.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from terra.datasets.ros.bag import message_bytes
from terra.errors import TerraError

# PointField.datatype -> NumPy kind and size (sensor_msgs/PointField constants INT8=1 .. FLOAT64=8).
DATATYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}
# field name -> seconds per unit of an integer field (float fields hold seconds, except where noted)
TIME_FIELDS = {"t": 1e-9, "time": 1.0, "offset_time": 1e-9, "timestamp": 1e-9}
SPLIT_TIME_FIELDS = (("time_sec", "time_nsec"), ("timestamp_sec", "timestamp_nsec"), ("t_sec", "t_nsec"))
ABSOLUTE_AFTER = 1.0e6  # seconds (11.6 days): no sweep is longer, no epoch time since 1970-01-13 shorter
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
    time_names = _time_fields(names)
    wanted = ["x", "y", "z"] + [n for n in ("intensity", *time_names, *LABEL_FIELDS) if n in names]
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
        _relative_times(cloud, idx, time_names, _stamp(msg)) if time_names else None,
        column("label", np.int32) if "label" in names else None,
        column("instance", np.int32) if "instance" in names else None,
    )


def _time_fields(names: set[str]) -> tuple[str, ...]:
    """The field(s) holding per-point time: a (seconds, nanoseconds) pair, one field, or none."""
    split = next((pair for pair in SPLIT_TIME_FIELDS if set(pair) <= names), None)
    if split is not None:
        return split
    return next(((n,) for n in TIME_FIELDS if n in names), ())


def _stamp(msg) -> tuple[int, int]:
    """(seconds, nanoseconds) of the message's header stamp ((0, 0) without a header)."""
    stamp = getattr(getattr(msg, "header", None), "stamp", None)
    return (int(getattr(stamp, "sec", 0)), int(getattr(stamp, "nanosec", 0))) if stamp is not None else (0, 0)


def _relative_times(cloud: np.ndarray, idx: np.ndarray, names: tuple[str, ...], stamp: tuple[int, int]) -> np.ndarray:
    """(N,) float64 seconds of the kept points relative to the header stamp (see the module docstring)."""
    if len(names) == 2:
        seconds = np.asarray(cloud[names[0]][idx], np.int64)
        nanos = np.asarray(cloud[names[1]][idx], np.int64)
        if seconds.size and np.abs(seconds).max() > ABSOLUTE_AFTER:
            seconds, nanos = seconds - stamp[0], nanos - stamp[1]
        return seconds + nanos * 1e-9
    column = cloud[names[0]][idx]
    times = np.asarray(column, np.float64)
    if column.dtype.kind != "f":
        times = times * TIME_FIELDS[names[0]]
    elif names[0] == "timestamp" and times.size and np.abs(times).max() > 1e12:
        times = times * 1e-9  # Livox's float64 nanoseconds (1e12 seconds would be the year 33658)
    if times.size and np.abs(times).max() > ABSOLUTE_AFTER:
        times = times - (stamp[0] + stamp[1] * 1e-9)
    return times
