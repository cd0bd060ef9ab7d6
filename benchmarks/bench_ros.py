"""Bag input and odometry speed (issue 10).

Targets: decoding a 128 x 1024 PointCloud2 with per-point time (Ouster layout: 48-byte points,
organized) <= 10 ms; reading a bag (LiDAR 10 Hz + one camera 10 Hz, JPEG) >= 5x faster than it
was recorded (index + every frame decoded: points, times, RGB image); KISS-ICP odometry on the
default 32 x 1024 simulated LiDAR >= 20 scans/s (registration only; scans rendered beforehand).

Usage: python benchmarks/bench_ros.py [--seconds 20] [--scans 100] [--quick]
Writes benchmarks/results/ros.json and prints a table.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path
from types import SimpleNamespace as NS
from typing import TYPE_CHECKING

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchtable import report  # noqa: E402

if TYPE_CHECKING:
    from terra.datasets.base import ClassTable, Frame

OUSTER = [
    ("x", 0, 7),
    ("y", 4, 7),
    ("z", 8, 7),
    ("intensity", 16, 7),
    ("t", 20, 6),
    ("reflectivity", 24, 4),
    ("ring", 26, 4),
    ("ambient", 28, 4),
    ("range", 32, 6),
]


def ouster_cloud(rows: int = 128, cols: int = 1024) -> NS:
    """An organized Ouster-style cloud: x y z at 0, intensity at 16, t (ns) at 20, ..., 48-byte points."""
    rng = np.random.default_rng(0)
    dtype = np.dtype(
        {
            "names": [f[0] for f in OUSTER],
            "formats": ["<f4", "<f4", "<f4", "<f4", "<u4", "<u2", "<u2", "<u2", "<u4"],
            "offsets": [f[1] for f in OUSTER],
            "itemsize": 48,
        }
    )
    cloud = np.zeros(rows * cols, dtype)
    for name in ("x", "y", "z"):
        cloud[name] = rng.normal(0, 20, rows * cols)
    cloud["x"][::17] = np.nan  # no-return pixels, as an organized cloud has them
    cloud["t"] = np.tile(np.arange(cols) * 97_656, rows)
    fields = [NS(name=n, offset=o, datatype=d, count=1) for n, o, d in OUSTER]
    return NS(
        height=rows,
        width=cols,
        fields=fields,
        is_bigendian=False,
        point_step=48,
        row_step=48 * cols,
        data=np.frombuffer(cloud.tobytes(), np.uint8),
    )


def bench_decode(repeat: int) -> tuple[list[float], float]:
    """Wall seconds per decode, and CPU seconds per decode (less disturbed by other processes)."""
    from terra.datasets.ros.pointcloud2 import decode_pointcloud2

    msg = ouster_cloud()
    decode_pointcloud2(msg)
    times = []
    cpu = time.process_time()
    for _ in range(repeat):
        start = time.perf_counter()
        decode_pointcloud2(msg)
        times.append(time.perf_counter() - start)
    return times, (time.process_time() - cpu) / repeat


def write_drive_bag(root: Path, seconds: float) -> tuple[Path, int]:
    """An mcap bag of `seconds` at 10 Hz: a 32 x 1024 cloud with per-point time, a 640 x 480 JPEG
    image with camera_info, /tf and /tf_static - content from the simulator's first frame."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    from terra.datasets.ros.messages import MessageFactory
    from terra.geometry import make_pose
    from terra.sim import simulate

    frame = simulate("tiny", 0)[0]
    cal = frame.cameras[0].calibration
    store = get_typestore(Stores.ROS2_HUMBLE)
    f = MessageFactory(store, ros1=False)
    n = int(seconds * 10)
    times = (np.arange(len(frame.points)) % 1024 * 97_656).astype(np.uint32)
    path = root / "drive"
    with Writer(path, version=Writer.VERSION_LATEST, storage_plugin=StoragePlugin.MCAP) as writer:
        types = {
            "/tf_static": "tf2_msgs/msg/TFMessage",
            "/tf": "tf2_msgs/msg/TFMessage",
            "/points": "sensor_msgs/msg/PointCloud2",
            "/cam/image_raw/compressed": "sensor_msgs/msg/CompressedImage",
            "/cam/camera_info": "sensor_msgs/msg/CameraInfo",
        }
        conns = {t: writer.add_connection(t, m, typestore=store) for t, m in types.items()}
        jpeg = f.compressed_image(0, "cam", frame.cameras[0].image)
        writer.write(
            conns["/tf_static"],
            0,
            f.serialize(
                f.tf([(0, "base", "lidar", np.eye(4)), (0, "base", "cam", np.linalg.inv(cal.T_cam_lidar))]),
                types["/tf_static"],
            ),
        )
        for k in range(n):
            ns = 1_700_000_000_000_000_000 + k * 100_000_000
            msgs = {
                "/tf": f.tf([(ns, "map", "base", make_pose(np.eye(3), np.array([0.15 * k, 0, 0])))]),
                "/points": f.pointcloud2(ns, "lidar", frame.points, frame.intensity, times),
                "/cam/camera_info": f.camera_info(ns, "cam", cal),
            }
            jpeg.header = f.header(ns, "cam")
            msgs["/cam/image_raw/compressed"] = jpeg
            for topic, msg in msgs.items():
                writer.write(conns[topic], ns, f.serialize(msg, types[topic]))
    return path, n


def bench_bag(seconds: float) -> dict:
    from terra.datasets.rosbag import RosbagDataset

    with tempfile.TemporaryDirectory() as tmp:
        path, n = write_drive_bag(Path(tmp), seconds)
        size = sum(p.stat().st_size for p in path.iterdir())
        start, cpu = time.perf_counter(), time.process_time()
        dataset = RosbagDataset(path, show_progress=False)
        indexed = time.perf_counter() - start
        points = 0
        for i in range(len(dataset)):
            frame = dataset[i]
            points += len(frame.points)
        total, cpu = time.perf_counter() - start, time.process_time() - cpu
        peak = _traced_read_peak(path)
    recorded = (n - 1) * 0.1
    return {
        "frames": n,
        "recorded_s": recorded,
        "index_s": indexed,
        "read_s": total,
        "speedup": recorded / total,
        "cpu_s": cpu,
        "traced_peak_mb": peak / 1e6,
        "speedup_cpu": recorded / cpu,
        "bag_mb": size / 1e6,
        "points": points,
    }


def _traced_read_peak(path: Path) -> int:
    """Peak bytes Python allocates while indexing and reading every frame of the bag (tracemalloc)."""
    import tracemalloc

    from terra.datasets.rosbag import RosbagDataset

    tracemalloc.start()
    dataset = RosbagDataset(path, show_progress=False)
    for i in range(len(dataset)):
        dataset[i]
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return peak


class FrameList:
    """Frames held in memory, as a Dataset, so that odometry's timing leaves the simulator out."""

    name = "bench"

    def __init__(self, frames: list[Frame], classes: ClassTable) -> None:
        self.frames, self.classes = frames, classes

    def __len__(self) -> int:
        return len(self.frames)

    def __getitem__(self, index: int) -> Frame:
        return self.frames[index]

    def global_map(self) -> np.ndarray | None:
        return None


def bench_odometry(scans: int) -> dict:
    """Speed on the default simulated LiDAR, and the drift on the same drive with and without the
    simulator's LiDAR wobble (its beam pattern otherwise repeats exactly from scan to scan)."""
    from terra.odometry.config import OdometryConfig
    from terra.odometry.kiss import run_odometry
    from terra.sim import simulate
    from terra.sim.config import SimConfig

    out: dict = {}
    for wobble in (0.0, 2.0):
        config = {
            "cameras": [],
            "lidar": {"wobble_deg": wobble},
            "route": {"frame_spacing": 0.15, "max_frames": scans},
            "frame_cache": 0,
        }
        sim = simulate("small", 0, SimConfig.model_validate(config))
        frames = [sim[i] for i in range(len(sim))]
        out["scans"] = len(frames)
        out["points_per_scan"] = float(np.mean([len(f.points) for f in frames]))
        for threads in (1, 0) if wobble == 0 else (1,):
            cpu = time.process_time()
            run = run_odometry(FrameList(frames, sim.classes), OdometryConfig(threads=threads), show_progress=False)
            key = f"threads{threads}" + ("" if wobble == 0 else f"_wobble{wobble:g}")
            out[f"cpu_s_per_scan_{key}"] = (time.process_time() - cpu) / len(frames)
            out[f"scans_per_s_{key}"] = run.scans_per_second
            out[f"errors_{key}"] = run.errors
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").partition("\n")[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="length of the recorded drive for the bag test")
    parser.add_argument("--scans", type=int, default=100, help="simulated scans for the odometry test")
    parser.add_argument("--quick", action="store_true", help="small sizes, to check the script runs")
    args = parser.parse_args()
    if args.quick:
        args.seconds, args.scans = 2.0, 10
    result = {
        "machine": platform.platform(),
        "cpus": os.cpu_count(),
        "python": platform.python_version(),
        "load_average_1min_at_start": os.getloadavg()[0],
        "quick": args.quick,
    }
    decode, decode_cpu = bench_decode(5 if args.quick else 50)
    result["decode_ms"] = {
        "median": 1e3 * statistics.median(decode),
        "min": 1e3 * min(decode),
        "max": 1e3 * max(decode),
        "cpu": 1e3 * decode_cpu,
    }
    result["bag"] = bench_bag(args.seconds)
    result["odometry"] = bench_odometry(args.scans)
    bag, odo = result["bag"], result["odometry"]
    rows = [
        (
            "PointCloud2 128x1024 decode, median (min; CPU)",
            "{median:.2f} ms ({min:.2f}; {cpu:.2f})".format(**result["decode_ms"]),
            "<= 10 ms",
        ),
        (
            f"bag read, {bag['frames']} scans + JPEG images, {bag['bag_mb']:.0f} MB mcap",
            f"{bag['read_s']:.2f} s (index {bag['index_s']:.2f} s) = {bag['speedup']:.1f}x real time "
            f"(CPU {bag['cpu_s']:.2f} s = {bag['speedup_cpu']:.1f}x), peak {bag['traced_peak_mb']:.0f} MB allocated",
            ">= 5x",
        ),
        (
            f"odometry, 32x1024 sim, {odo['scans']} scans, 1 thread",
            f"{odo['scans_per_s_threads1']:.1f} scans/s (CPU {1 / odo['cpu_s_per_scan_threads1']:.1f}/s)",
            ">= 20",
        ),
        ("odometry, all threads", f"{odo['scans_per_s_threads0']:.1f} scans/s", "-"),
        (
            "odometry drift, that drive / with 2 deg LiDAR wobble",
            f"{odo['errors_threads1']['drift_percent']:.1f} % / "
            f"{odo['errors_threads1_wobble2']['drift_percent']:.2f} % "
            f"of {odo['errors_threads1']['distance_m']:.1f} m",
            "< 1 %",
        ),
    ]
    report(rows, result, Path(__file__).parent / "results" / "ros.json")


if __name__ == "__main__":
    main()
