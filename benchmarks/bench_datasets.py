"""Real-data readers and lenses (issue 11): what reading a frame costs at real sizes, next to the
mapping stage's 50 ms-per-frame fusion budget, and what the authors' 14-coefficient lens costs.

- the authors' layout: OS1-128 scans (131,072 points), three 768 x 480 JPEG cameras calibrated
  from their msmap config (intrinsics from the YAML, extrinsics per scan);
- a KITTI raw drive: HDL-64 sized scans (120,000 points), two 1242 x 375 PNG cameras, OXTS;
- OXTS -> poses for a 5,000-packet drive; the 14-coefficient lens inverse over a whole image.

Usage: python benchmarks/bench_datasets.py [--frames 20] [--out benchmarks/results/datasets.json]
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

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.benchtable import report  # noqa: E402
from terra.datasets import open_dataset  # noqa: E402
from terra.datasets.base import CameraFrame, ClassTable, Frame, SemanticClass  # noqa: E402
from terra.geometry import CameraCalibration, make_pose, pixel_rays, project_points  # noqa: E402


class Synthetic:
    """`frames` frames of random points and images with the given cameras (a Dataset)."""

    classes = ClassTable([SemanticClass(0, "unlabeled")])

    def __init__(self, name: str, frames: int, points: int, cameras: list[CameraCalibration]) -> None:
        self.name, self.count, self.points, self.cameras = name, frames, points, cameras

    def __len__(self) -> int:
        return self.count

    def __getitem__(self, index: int) -> Frame:
        rng = np.random.default_rng(index)
        cams = []
        for cal in self.cameras:
            # Smooth images (as real ones are), so the JPEG / PNG sizes are realistic.
            base = rng.integers(0, 255, (cal.height // 8 + 1, cal.width // 8 + 1, 3)).astype(np.uint8)
            image = np.repeat(np.repeat(base, 8, 0), 8, 1)[: cal.height, : cal.width]
            cams.append(CameraFrame(cal, 10.0 + 0.1 * index, image))
        pose = make_pose(np.eye(3), np.array([1.5 * index, 0.1 * index, 0.0]))
        return Frame(
            index,
            10.0 + 0.1 * index,
            rng.uniform(-50, 50, (self.points, 3)).astype(np.float32),
            pose,
            cams,
            rng.uniform(0, 1, self.points).astype(np.float32),
        )

    def global_map(self):
        return None


def time_reads(path: Path, options: dict | None = None) -> dict:
    start = time.perf_counter()
    ds = open_dataset(path, options=options)
    opened = time.perf_counter() - start
    per_frame = []
    for i in range(len(ds)):
        t = time.perf_counter()
        ds[i]
        per_frame.append(time.perf_counter() - t)
    return {
        "open_s": opened,
        "frame_ms_median": 1000 * statistics.median(per_frame),
        "frame_ms_max": 1000 * max(per_frame),
        "frames": len(ds),
    }


def authors_layout(root: Path, frames: int) -> tuple[Path, Path]:
    import yaml

    from terra.sim.writer import write_dataset
    from tests.datasets.fixtures_authors import NUNNS_PARK_YAML, rig

    folder = write_dataset(Synthetic("field", frames, 131_072, rig(NUNNS_PARK_YAML)), root / "field", progress=False)
    for name in ("terra_dataset.json", "msmap_camera_config.yaml"):
        (folder / name).unlink()
    config = root / "msmap_multicam.yaml"
    config.write_text(NUNNS_PARK_YAML)
    assert yaml.safe_load(config.read_text())["num_cams"] == 3
    return folder, config


def kitti_drive(root: Path, frames: int) -> Path:
    from terra.datasets.kitti_raw_writer import write_kitti_raw

    K = np.array([[721.5377, 0.0, 609.5593], [0.0, 721.5377, 172.854], [0.0, 0.0, 1.0]])
    R = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
    cams = [
        CameraCalibration("left", 1242, 375, K, np.zeros(0), make_pose(R, np.array([0.0, -0.08, -0.27]))),
        CameraCalibration("right", 1242, 375, K, np.zeros(0), make_pose(R, np.array([-0.54, -0.08, -0.27]))),
    ]
    write_kitti_raw(Synthetic("drive", frames, 120_000, cams), root / "kitti", show_progress=False)
    return root / "kitti"


def lens_costs() -> dict:
    from tests.core.test_lens import AUTHORS_LENSES

    K, dist = AUTHORS_LENSES["nunns-park-cam3"]
    seconds = []
    for _ in range(3):
        cam = CameraCalibration("c", 768, 480, K, dist)
        start = time.perf_counter()
        pixel_rays(cam)
        seconds.append(time.perf_counter() - start)
    # A full turn of an OS1-128 in the camera frame: 128 beams x 1024 columns at 3..60 m.
    rng = np.random.default_rng(0)
    azimuth = np.repeat(np.linspace(-np.pi, np.pi, 1024, endpoint=False), 128)
    elevation = np.tile(np.radians(np.linspace(-22.5, 22.5, 128)), 1024)
    rng_m = rng.uniform(3.0, 60.0, azimuth.size)
    points = (
        np.stack([np.sin(azimuth) * np.cos(elevation), -np.sin(elevation), np.cos(azimuth) * np.cos(elevation)], 1)
        * rng_m[:, None]
    )
    project_points(points, cam)
    start = time.perf_counter()
    project_points(points, cam)
    return {
        "inverse_whole_image_s_median": statistics.median(seconds),
        "project_131k_points_ms": 1000 * (time.perf_counter() - start),
    }


def oxts_cost(packets: int = 5000) -> float:
    from terra.datasets.oxts import normalise_poses, packets_from_poses, world_poses

    T = np.tile(np.eye(4), (packets, 1, 1))
    T[:, 0, 3] = np.arange(packets) * 1.0
    data = packets_from_poses(T, np.arange(packets) * 0.1, (49.011, 8.424, 112.0))
    start = time.perf_counter()
    normalise_poses(world_poses(data))
    return 1000 * (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").partition("\n")[0])
    parser.add_argument("--frames", type=int, default=20)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "datasets.json")
    args = parser.parse_args()
    result = {
        "machine": platform.platform(),
        "cpus": os.cpu_count(),
        "load_average_1min_at_start": os.getloadavg()[0],
        "python": platform.python_version(),
        "date": time.strftime("%Y-%m-%d"),
    }
    with tempfile.TemporaryDirectory() as tmp:
        folder, config = authors_layout(Path(tmp), args.frames)
        result["authors_layout"] = time_reads(folder, {"camera_config": config})
        result["kitti_raw"] = time_reads(kitti_drive(Path(tmp), args.frames))
    result["lens_14_coefficients"] = lens_costs()
    result["oxts_5000_packets_ms"] = oxts_cost()
    a, k, lens = result["authors_layout"], result["kitti_raw"], result["lens_14_coefficients"]
    rows = [
        ("authors' layout: open (YAML + pairing)", f"{a['open_s']:.2f} s for {a['frames']} scans", "-"),
        (
            "authors' layout: one frame (131k pts, 3 JPEG)",
            f"{a['frame_ms_median']:.1f} ms (max {a['frame_ms_max']:.1f})",
            "<= 50 ms",
        ),
        ("KITTI raw: open (calib, OXTS)", f"{k['open_s']:.2f} s for {k['frames']} scans", "-"),
        (
            "KITTI raw: one frame (120k pts, 2 PNG)",
            f"{k['frame_ms_median']:.1f} ms (max {k['frame_ms_max']:.1f})",
            "<= 50 ms",
        ),
        ("OXTS -> poses, 5000 packets", f"{result['oxts_5000_packets_ms']:.1f} ms", "-"),
        ("14-coef lens inverse, 768 x 480", f"{lens['inverse_whole_image_s_median']:.2f} s", "once per camera"),
        ("14-coef projection, one 360-degree OS1-128 scan", f"{lens['project_131k_points_ms']:.1f} ms", "-"),
    ]
    report(rows, result, args.out)


if __name__ == "__main__":
    main()
