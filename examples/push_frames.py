"""Push the frames of a dataset folder to `terra serve --live`, as a robot-side program would.

Needs numpy and the Python standard library only (no Terra): it reads a terra-folder dataset (what
`python -m terra sim --out DIR` writes, or any folder with a terra_dataset.json) and sends, per
scan, one POST /frames whose body is an uncompressed .npz (the wire format in terra/live/wire.py
and the README's "Live mapping over HTTP"): the scan, its pose as [tx ty tz qx qy qz qw], the
stamp, the per-point labels and, per camera, the JPEG and label PNG files as they are (the service
decodes them as `terra map` does, so the live map equals `terra map DIR`, byte for byte).

    terra serve drive.terra --live --classes DIR/classes.json --allow-writes &
    python examples/push_frames.py DIR http://127.0.0.1:8765 --rate 10 --snapshot

A refused frame (HTTP 4xx) is reported with the service's one-line reason and the next is sent.
Exit status: 0 when every frame was taken, 1 when some were refused, 2 for a folder it cannot read.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import sys
import time
import urllib.error
import urllib.request
import zipfile
from collections.abc import Iterator
from pathlib import Path

import numpy as np

POSES, SCANS, LABELS, META = "transformations_lidar2global", "lidar_pc", "lidar_labels", "terra_dataset.json"
MAX_GAP = 0.2  # seconds between a pose and its scan or images, as terra-folder's reader allows


# ------------------------------------------------------------------------------- reading the folder
def stamped(folder: Path, prefix: str, suffix: str) -> list[tuple[float, Path]]:
    """(stamp, file) of `folder`'s files named PREFIX<seconds>SUFFIX, by stamp."""
    found = []
    for path in folder.glob(f"{prefix}*{suffix}") if folder.is_dir() else []:
        try:
            found.append((float(path.name[len(prefix) : -len(suffix)]), path))
        except ValueError:
            continue
    return sorted(found, key=lambda item: item[0])


def nearest(files: list[tuple[float, Path]], t: float) -> tuple[Path | None, float]:
    """The file whose stamp is nearest `t` (the earlier on a tie) and its gap in seconds."""
    if not files:
        return None, float("inf")
    best = min(files, key=lambda item: (abs(item[0] - t), item[0]))
    return best[1], abs(best[0] - t)


def read_cameras(root: Path) -> dict[str, dict]:
    """The calibrations of terra_dataset.json by camera number ({} for a folder without cameras)."""
    meta_file = root / META
    meta = json.loads(meta_file.read_text()) if meta_file.is_file() else {}
    first = int(meta.get("first_camera") or 0)
    return {str(first + i): calibration for i, calibration in enumerate(meta.get("cameras") or [])}


def read_frames(root: Path, cameras: dict[str, dict]) -> Iterator[dict[str, np.ndarray]]:
    """The arrays of each frame of the folder, in time order (a scan lacking its scan file or an
    image within MAX_GAP seconds is left out, as `terra map` leaves it out)."""
    scans = stamped(root / SCANS, "lidar_pc_", ".npy")
    images = {c: stamped(root / f"camera{c}_images", f"cam{c}_img_", ".jpg") for c in cameras}
    for t, pose_file in stamped(root / POSES, "transform_lidar_to_map_", ".npy"):
        scan_file, gap = nearest(scans, t)
        picks = {c: nearest(images[c], t) for c in cameras}
        if scan_file is None or max([gap, *(g for _, g in picks.values())]) > MAX_GAP:
            print(f"push_frames: {pose_file.name}: no scan or image within {MAX_GAP} s; left out", file=sys.stderr)
            continue
        scan = np.load(scan_file, allow_pickle=False)
        arrays = {
            "points": np.ascontiguousarray(scan[:, :3], dtype=np.float32),
            "intensity": scan[:, 3].astype(np.float32),
            "pose_xyz_quat": np.load(pose_file, allow_pickle=False).astype(np.float64),
            "stamp": np.float64(t),
        }
        label_file = root / LABELS / f"lidar_labels_{t:.6f}.npy"
        if label_file.is_file():
            labels = np.load(label_file, allow_pickle=False)
            arrays["labels"], arrays["instances"] = labels[:, 0].astype(np.int32), labels[:, 1].astype(np.int32)
        for c, (image_file, _) in picks.items():
            if image_file is not None:  # always: a missing image is an infinite gap
                arrays.update(camera_arrays(root, c, image_file))
        yield arrays


def camera_arrays(root: Path, c: str, image_file: Path) -> dict[str, np.ndarray]:
    """Camera c's image and label files as they are (bytes in uint8 arrays), with the image's stamp."""
    image_stamp = float(image_file.stem.rsplit("_", 1)[-1])
    arrays = {f"image_{c}": file_bytes(image_file), f"image_stamp_{c}": np.float64(image_stamp)}
    for name, folder, prefix in (("semantic", "semantic", "sem"), ("instance", "instance", "inst")):
        path = root / f"camera{c}_{folder}" / f"cam{c}_{prefix}_{image_stamp:.6f}.png"
        if path.is_file():
            arrays[f"{name}_{c}"] = file_bytes(path)
    return arrays


def file_bytes(path: Path) -> np.ndarray:
    return np.frombuffer(path.read_bytes(), dtype=np.uint8)


def encode(arrays: dict[str, np.ndarray]) -> bytes:
    """One frame as the body of POST /frames: an uncompressed .npz, as numpy.savez writes it (spelt
    out so that no array is ever pickled, whatever the numpy version)."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_STORED) as archive:
        for name, array in arrays.items():
            with archive.open(f"{name}.npy", "w", force_zip64=True) as member:
                np.lib.format.write_array(member, np.asanyarray(array), allow_pickle=False)
    return buffer.getvalue()


# ------------------------------------------------------------------------------------- the service
class Service:
    """The few calls a robot makes to `terra serve --live`."""

    def __init__(self, url: str, token: str | None = None, timeout: float = 120.0):
        self.url, self.token, self.timeout = url.rstrip("/"), token, timeout

    def call(self, method: str, path: str, body: bytes | None = None, kind: str = "application/json") -> tuple:
        """(HTTP status, the JSON answer)."""
        request = urllib.request.Request(self.url + path, data=body, method=method)
        if body is not None:
            request.add_header("Content-Type", kind)
        if self.token:
            request.add_header("Authorization", f"Bearer {self.token}")
        try:
            with urllib.request.urlopen(request, timeout=self.timeout) as response:
                return response.status, json.loads(response.read())
        except urllib.error.HTTPError as exc:
            return exc.code, json.loads(exc.read() or b"{}")

    def set_cameras(self, cameras: dict[str, dict]) -> tuple:
        return self.call("POST", "/cameras", json.dumps({"cameras": cameras}).encode())

    def push(self, arrays: dict[str, np.ndarray]) -> tuple:
        return self.call("POST", "/frames", encode(arrays), "application/x-npz")


def push_folder(root: Path, service: Service, rate: float | None = None, snapshot: bool = False) -> dict:
    """Push every frame of the folder `root` (at most `rate` frames a second); the counts, and with
    `snapshot` the version committed at the end."""
    cameras = read_cameras(root)
    if cameras:
        status, answer = service.set_cameras(cameras)
        if status != 200:
            raise RuntimeError(f"POST /cameras: {status} {answer.get('error', answer)}")
    sent = refused = 0
    began = time.monotonic()
    for arrays in read_frames(root, cameras):
        if rate:
            time.sleep(max(0.0, began + sent / rate - time.monotonic()))
        status, answer = service.push(arrays)
        sent += 1
        if status != 200:
            refused += 1
            print(f"push_frames: frame at {float(arrays['stamp']):.6f} s refused ({status}): {answer.get('error')}")
    summary = {"sent": sent, "refused": refused, "seconds": round(time.monotonic() - began, 3)}
    if snapshot:
        status, answer = service.call("POST", "/snapshot", b"{}")
        summary["version"] = answer.get("version") if status == 200 else None
    return summary


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument("dataset", type=Path, help="a terra-folder dataset (e.g. `python -m terra sim` output)")
    parser.add_argument("url", help="the service, e.g. http://127.0.0.1:8765")
    parser.add_argument("--token", default=os.environ.get("TERRA_SERVE_TOKEN"), help="bearer token, if it has one")
    parser.add_argument("--rate", type=float, default=None, help="frames a second (default: as fast as taken)")
    parser.add_argument("--snapshot", action="store_true", help="commit a version when every frame is sent")
    args = parser.parse_args(argv)
    if not (args.dataset / POSES).is_dir():
        print(f"push_frames: {args.dataset}: not a terra-folder dataset (no {POSES}/)", file=sys.stderr)
        return 2
    summary = push_folder(args.dataset, Service(args.url, args.token), args.rate, args.snapshot)
    print(json.dumps(summary))
    return 1 if summary["refused"] else 0


if __name__ == "__main__":
    sys.exit(main())
