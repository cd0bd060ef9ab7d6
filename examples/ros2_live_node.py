"""A ROS 2 node that maps while the robot drives: terra.live.Session fed from rclpy callbacks.

Subscribes to a LiDAR cloud (sensor_msgs/PointCloud2), one camera (sensor_msgs/Image and its
CameraInfo) and tf; each scan is fused with the newest image within 50 ms of it and its pose
map -> LiDAR looked up in tf at the scan's stamp; every 2 s the map is committed as the bundle's
next version, which `terra serve OUT` and `terra find OUT ...` answer from meanwhile.

    python examples/ros2_live_node.py --out live.terra --cloud /lidar/points \\
        --image /camera/image_raw --info /camera/camera_info --classes classes.json

Needs a ROS 2 installation (rclpy, tf2_ros, sensor_msgs); Terra itself never imports ROS.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def main() -> int:
    parser = argparse.ArgumentParser(
        description="Map while the robot drives: terra.live.Session fed from rclpy callbacks."
    )
    parser.add_argument("--out", type=Path, required=True, help="bundle folder the live map is committed to")
    parser.add_argument("--cloud", default="/lidar/points")
    parser.add_argument("--image", default="/camera/image_raw")
    parser.add_argument("--info", default="/camera/camera_info")
    parser.add_argument("--map-frame", default="map")
    parser.add_argument("--classes", type=Path, help="classes.json of the labels (default: unlabeled only)")
    parser.add_argument("--resume", action="store_true", help="continue the map already in --out")
    args = parser.parse_args()
    try:
        import rclpy  # type: ignore[import-not-found]  # pyright: ignore[reportMissingImports]
        from rclpy.node import Node  # pyright: ignore[reportMissingImports]
        from rclpy.time import Time  # pyright: ignore[reportMissingImports]
        from sensor_msgs.msg import CameraInfo, Image, PointCloud2  # pyright: ignore[reportMissingImports]
        from tf2_ros import Buffer, TransformException, TransformListener  # pyright: ignore[reportMissingImports]
    except ImportError:
        print("this example needs ROS 2 (rclpy, tf2_ros, sensor_msgs): source your ROS 2 setup first", file=sys.stderr)
        return 2

    from terra.datasets.base import ClassTable, SemanticClass
    from terra.datasets.folder_io import read_classes
    from terra.errors import TerraError
    from terra.live import Session
    from terra.live.ros import calibration_of, camera_frame, frame_arguments, pose_of, stamp_of

    classes = (read_classes(args.classes.parent) if args.classes else None) or ClassTable(
        [SemanticClass(0, "unlabeled")]
    )
    session = Session(args.out, classes, graph=False, resume=args.resume, overwrite=not args.resume)

    class LiveMapper(Node):
        def __init__(self) -> None:
            super().__init__("terra_live")
            self.tf = Buffer()
            self.listener = TransformListener(self.tf, self)
            self.info, self.image, self.calibration = None, None, None
            self.create_subscription(CameraInfo, args.info, self.on_info, 5)
            self.create_subscription(Image, args.image, self.on_image, 5)
            self.create_subscription(PointCloud2, args.cloud, self.on_cloud, 5)
            self.create_timer(2.0, self.on_timer)

        def on_info(self, msg) -> None:
            self.info = msg

        def on_image(self, msg) -> None:
            self.image = msg

        def mount(self, camera_frame_id: str, lidar_frame_id: str):
            """T_cam_lidar: the camera's optical frame from the LiDAR's, once, from tf_static."""
            if self.calibration is None and self.info is not None:
                seen = self.tf.lookup_transform(camera_frame_id, lidar_frame_id, Time())
                self.calibration = calibration_of(self.info, "camera", pose_of(seen))
            return self.calibration

        def on_cloud(self, cloud) -> None:
            stamp = Time.from_msg(cloud.header.stamp)
            try:
                pose = pose_of(self.tf.lookup_transform(args.map_frame, cloud.header.frame_id, stamp))
                images = []
                image = self.image
                if image is not None and abs(stamp_of(image) - stamp_of(cloud)) <= 0.05:
                    calibration = self.mount(image.header.frame_id, cloud.header.frame_id)
                    if calibration is not None:
                        images.append(camera_frame(image, calibration))
                session.add_frame(**frame_arguments(cloud, pose, images))
            except TransformException as exc:
                self.get_logger().warn(f"no pose for the scan at {stamp_of(cloud):.3f} s: {exc}")
            except TerraError as exc:  # a malformed message or frame: refused, counted, never fused
                self.get_logger().warn(str(exc))

        def on_timer(self) -> None:
            try:
                snap = session.snapshot()
                self.get_logger().info(f"version {snap.version}: {snap.frames} frames, map time {snap.map_time}")
            except TerraError as exc:  # nothing fused yet
                self.get_logger().info(str(exc))

    rclpy.init()
    node = LiveMapper()
    try:
        rclpy.spin(node)
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
