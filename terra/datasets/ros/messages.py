"""Building ROS messages (for writing bags): PointCloud2, Image, CompressedImage, CameraInfo, TF.

Messages are instances of a `rosbags` typestore's classes, so the same code builds ROS 1
(noetic: Header with seq, CameraInfo D/K/R/P) and ROS 2 (humble: d/k/r/p) messages; the bag
writer serializes them with that typestore.
"""

from __future__ import annotations

import io

import numpy as np

from terra import lens
from terra.geometry import CameraCalibration, pose_to_xyz_quat

POINT_FIELDS = (
    ("x", 0, 7),
    ("y", 4, 7),
    ("z", 8, 7),
    ("intensity", 12, 7),
    ("t", 16, 6),
    ("label", 20, 6),
    ("instance", 24, 6),
)
POINT_STEP = 28


class MessageFactory:
    """Message objects of one typestore (`ros1` selects the ROS 1 field names)."""

    def __init__(self, typestore, ros1: bool) -> None:
        self.store = typestore
        self.ros1 = ros1
        if "tf2_msgs/msg/TFMessage" not in typestore.types:  # rosbags' noetic store lacks tf2_msgs
            from rosbags.typesys import get_types_from_msg

            typestore.register(
                get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage")
            )
        self._t = typestore.types

    def header(self, stamp_ns: int, frame_id: str, seq: int = 0):
        stamp = self._t["builtin_interfaces/msg/Time"](
            sec=int(stamp_ns // 1_000_000_000), nanosec=int(stamp_ns % 1_000_000_000)
        )
        if self.ros1:
            return self._t["std_msgs/msg/Header"](seq=seq, stamp=stamp, frame_id=frame_id)
        return self._t["std_msgs/msg/Header"](stamp=stamp, frame_id=frame_id)

    def pointcloud2(
        self,
        stamp_ns: int,
        frame_id: str,
        points: np.ndarray,
        intensity: np.ndarray | None = None,
        times_ns: np.ndarray | None = None,
        labels: np.ndarray | None = None,
        instances: np.ndarray | None = None,
    ):
        """An unorganized little-endian cloud: x, y, z, intensity float32, t uint32 (ns after
        the stamp, Ouster's convention), label and instance uint32 (written when given)."""
        n = len(points)
        present = {"intensity": intensity, "t": times_ns, "label": labels, "instance": instances}
        fields = [f for f in POINT_FIELDS if f[0] in ("x", "y", "z") or present[f[0]] is not None]
        dtype = np.dtype(
            {
                "names": [f[0] for f in fields],
                "formats": ["<f4" if f[2] == 7 else "<u4" for f in fields],
                "offsets": [f[1] for f in fields],
                "itemsize": POINT_STEP,
            }
        )
        cloud = np.zeros(n, dtype)
        for axis, name in enumerate("xyz"):
            cloud[name] = points[:, axis]
        for name, values in present.items():
            if values is not None:
                cloud[name] = values
        field_type = self._t["sensor_msgs/msg/PointField"]
        return self._t["sensor_msgs/msg/PointCloud2"](
            header=self.header(stamp_ns, frame_id),
            height=1,
            width=n,
            fields=[
                field_type(name=name, offset=offset, datatype=datatype, count=1) for name, offset, datatype in fields
            ],
            is_bigendian=False,
            point_step=POINT_STEP,
            row_step=POINT_STEP * n,
            data=np.frombuffer(cloud.tobytes(), np.uint8),
            is_dense=True,
        )

    def image(self, stamp_ns: int, frame_id: str, pixels: np.ndarray, encoding: str = "rgb8"):
        """A sensor_msgs/Image: (H, W, 3) uint8 for rgb8, (H, W) ids for mono16 / 32SC1 (little endian)."""
        pixels = np.ascontiguousarray(pixels)
        height, width = pixels.shape[:2]
        dtype = {"mono16": "<u2", "32SC1": "<i4"}.get(encoding, np.uint8)
        data = pixels.astype(dtype).tobytes()
        return self._t["sensor_msgs/msg/Image"](
            header=self.header(stamp_ns, frame_id),
            height=height,
            width=width,
            encoding=encoding,
            is_bigendian=0,
            step=len(data) // height,
            data=np.frombuffer(data, np.uint8),
        )

    def compressed_image(self, stamp_ns: int, frame_id: str, rgb: np.ndarray, quality: int = 92):
        """A JPEG sensor_msgs/CompressedImage (Pillow, no chroma subsampling, as Terra's folders write)."""
        from PIL import Image

        buf = io.BytesIO()
        Image.fromarray(np.ascontiguousarray(rgb, np.uint8)).save(buf, format="JPEG", quality=quality, subsampling=0)
        return self._t["sensor_msgs/msg/CompressedImage"](
            header=self.header(stamp_ns, frame_id),
            format="rgb8; jpeg compressed rgb8",
            data=np.frombuffer(buf.getvalue(), np.uint8),
        )

    def camera_info(self, stamp_ns: int, frame_id: str, cal: CameraCalibration):
        """CameraInfo of a calibration: plumb_bob (5 coefficients, padded from 4), rational_polynomial
        (8) or equidistant (4); other pinhole lengths (12, 14) have no ROS model name."""
        if cal.model == lens.FISHEYE:
            model, dist = "equidistant", cal.dist
        elif cal.dist.size <= 5:
            model, dist = "plumb_bob", np.pad(cal.dist, (0, 5 - cal.dist.size))
        elif cal.dist.size == 8:
            model, dist = "rational_polynomial", cal.dist
        else:
            raise ValueError(f"camera {cal.name}: {cal.dist.size} coefficients have no ROS distortion model name")
        K = cal.K.ravel()
        P = np.hstack([cal.K, np.zeros((3, 1))]).ravel()
        arrays = {"d": np.asarray(dist, float), "k": K, "r": np.eye(3).ravel(), "p": P}
        if self.ros1:
            arrays = {k.upper(): v for k, v in arrays.items()}
        roi = self._t["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        return self._t["sensor_msgs/msg/CameraInfo"](
            header=self.header(stamp_ns, frame_id),
            height=int(cal.height),
            width=int(cal.width),
            distortion_model=model,
            binning_x=0,
            binning_y=0,
            roi=roi,
            **arrays,
        )

    def tf(self, transforms: list[tuple[int, str, str, np.ndarray]]):
        """A tf2_msgs/TFMessage from (stamp ns, parent, child, T_parent_child 4x4) rows."""
        t = self._t
        rows = []
        for stamp_ns, parent, child, T in transforms:
            x = pose_to_xyz_quat(T)
            transform = t["geometry_msgs/msg/Transform"](
                translation=t["geometry_msgs/msg/Vector3"](x=x[0], y=x[1], z=x[2]),
                rotation=t["geometry_msgs/msg/Quaternion"](x=x[3], y=x[4], z=x[5], w=x[6]),
            )
            rows.append(
                t["geometry_msgs/msg/TransformStamped"](
                    header=self.header(stamp_ns, parent), child_frame_id=child, transform=transform
                )
            )
        return t["tf2_msgs/msg/TFMessage"](transforms=rows)

    def navsatfix(self, stamp_ns: int, frame_id: str, lat: float, lon: float, alt: float, std: float):
        """A sensor_msgs/NavSatFix with a GPS fix at lat, lon (degrees), alt (metres) and, when `std`
        (metres) is finite, a diagonal covariance of std^2 east and north, (2 std)^2 up."""
        t = self._t
        status = t["sensor_msgs/msg/NavSatStatus"](status=0, service=1)
        known = bool(np.isfinite(std))
        variance = [std**2, std**2, (2 * std) ** 2] if known else [0.0, 0.0, 0.0]
        return t["sensor_msgs/msg/NavSatFix"](
            header=self.header(stamp_ns, frame_id),
            status=status,
            latitude=float(lat),
            longitude=float(lon),
            altitude=float(alt),
            position_covariance=np.diag(variance).reshape(-1).astype(np.float64),
            position_covariance_type=2 if known else 0,
        )

    def serialize(self, msg, msgtype: str) -> bytes:
        data = self.store.serialize_ros1(msg, msgtype) if self.ros1 else self.store.serialize_cdr(msg, msgtype)
        return bytes(data)
