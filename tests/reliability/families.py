"""Fuzz families of issue 24 section 4: values rather than byte edits, each drawn from a family of
inputs that once escaped as tracebacks, run through the command line or the service:

- node ids: 20+ digits, thousands of digits, non-ASCII digits ('²', '٣', '１'), signs, exponents;
- coordinates: 1e308, -1e308, 1e309, NaN, infinities, denormals, -1, digit strings;
- queries: lone surrogates, control characters, NUL, 10,000 characters, right-to-left marks;
- tf quaternions: zero, non-finite, overflowing or underflowing norms, in /tf and /tf_static of
  ROS 1 and ROS 2 bags written here;
- images: a PNG or JPEG header declaring 30000 x 30000 (or 0 x 0) pixels in a dataset's image files
  and in a bag's CompressedImage data;
- truncated bags: a ROS 1 bag or ROS 2 mcap cut at every small offset (case number mod 257) or at
  a random one;
- calibration values: a number of a KITTI raw or SemanticKITTI calibration file, or of a
  terra-folder camera file, replaced by an extreme one;
- HTTP requests to `terra serve` (FastAPI's TestClient) carrying the values above.

Each case is judged as every fuzz case is (tests/reliability/fuzzing.py): exit 0 with a valid result
or exit 2 with one line (HTTP: a 2xx JSON answer or a 4xx one-line JSON error), nothing changed
but the output.
"""

from __future__ import annotations

import json
import random
import re
import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

QUERY_TEXT = "find the dumpster"

DIGITS = ["²", "٣", "١٢", "１２", "߁", "𝟘", "৩", "1²", "٣4"]
NUMBER_WORDS = [
    "-1",
    "-0",
    "+1",
    "0",
    "1e308",
    "-1e308",
    "1e309",
    "-1e309",
    "inf",
    "-inf",
    "Infinity",
    "nan",
    "NaN",
    "-nan",
    "1e-320",
    "4.9e-324",
    "0x10",
    "1_000",
    " 1",
    "1 ",
    "",
    "１e３",
    "1e",
    ".",
    "-",
    "9223372036854775807",
    "9223372036854775808",
    "18446744073709551615",
    "18446744073709551616",
    "-9223372036854775809",
]
FLOATS = [1e308, -1e308, float("inf"), float("-inf"), float("nan"), 1e-320, -1.0, 0.0, -0.0, 1e154, 1e-200, 2.0**64]


def number_text(rng: random.Random) -> str:
    """One text a user or a request might give where a number is expected."""
    roll = rng.randrange(4)
    if roll == 0:
        length = rng.choice([19, 20, 21, 25, 64, 309, 1000, 5000, 10_000])
        if rng.random() < 0.5:
            return rng.choice(["9", "1"]) * length
        return str(rng.randrange(1, 10)) + "".join(rng.choice("0123456789") for _ in range(length - 1))
    if roll == 1:
        return rng.choice(DIGITS)
    return rng.choice(NUMBER_WORDS)


def node_text(rng: random.Random) -> str:
    prefix = rng.choice(["", "", "p", "R", "O", "S", "x", "ß", "P", "r"])
    return prefix + number_text(rng)


def query_text(rng: random.Random) -> str:
    """A query holding what text encoders and terminals choke on."""
    pieces = [
        "\ud800",
        "\udfff",
        "\ud83d",
        "\x00",
        "\n",
        "\x1b[2J",
        "\u202e",
        "\ufeff",
        "é",
        "dumpster",
        " ",
        "\t",
        "\U0001f5d1",
        "\u0301",
    ]
    if rng.random() < 0.1:
        return rng.choice(["a", "dumpster "]) * rng.choice([2_000, 10_000])
    return "".join(rng.choice(pieces) for _ in range(rng.randrange(1, 8)))


@dataclass
class Made:
    """One drawn case: what was drawn (words), and an argv with its output path or an HTTP request."""

    mutation: str
    argv: list | None = None
    output: Path | None = None
    request: tuple[str, str, bytes | None] | None = None  # (method, path with query, JSON body)


@dataclass(frozen=True)
class Family:
    """A fuzz family: `seed` is what run_case copies into the case ("bundle", a dataset format);
    `make(seeds, copy, case, rng)` draws one case on that copy."""

    name: str
    seed: str
    make: Callable[[Any, Path, Path, random.Random], Made]


# ---------------------------------------------------------------------------------- CLI families
def _node(seeds, copy: Path, case: Path, rng: random.Random) -> Made:
    node = node_text(rng)
    argv = ["node", copy, "--", node] if rng.random() < 0.5 else ["node", copy, node]
    return Made(f"node {node[:60]!r} ({len(node)} chars)", argv + (["--json"] if rng.random() < 0.3 else []))


def _coordinates(seeds, copy: Path, case: Path, rng: random.Random) -> Made:
    x, y = number_text(rng), rng.choice([number_text(rng), "1.5", "-1"])
    if rng.random() < 0.5:
        argv = ["node", copy, "--at", x, y]
    else:
        argv = ["plan", copy, "--from-xy", f"{x},{y}", "--to-node", "0"]
    return Made(f"coordinates {x[:40]!r}, {y[:40]!r}", argv)


def _queries(seeds, copy: Path, case: Path, rng: random.Random) -> Made:
    query = query_text(rng)
    argv = rng.choice(
        [
            ["find", copy, query],
            ["find", copy, query, "--method", "3dsg"],
            ["monitor", copy, query],
            ["plan", copy, "--to", query, "--from-node", "0"],
            ["plan", copy, "--from", query, "--to", QUERY_TEXT],
        ]
    )
    return Made(f"query {query[:40]!r} ({len(query)} chars)", argv)


# ------------------------------------------------------------------------------------ bag families
def _quaternion(rng: random.Random) -> tuple[float, float, float, float]:
    choice = rng.randrange(5)
    if choice == 0:
        return (0.0, 0.0, 0.0, 0.0)
    if choice == 1:
        return (1e-200, 1e-200, 0.0, 1e-200)  # its norm underflows to zero
    if choice == 2:
        return (1e200, 1e200, 0.0, 1e200)  # its norm overflows to infinity
    q = [rng.choice([0.0, 1.0, 0.5])] * 4
    q[rng.randrange(4)] = rng.choice(FLOATS)
    return (q[0], q[1], q[2], q[3])


def _tf_bag(seeds, copy: Path, case: Path, rng: random.Random) -> Made:
    """A small bag whose only transform (map -> velodyne) has a degenerate rotation or translation."""
    import numpy as np

    from tests.datasets.fixtures_ros import factory_for, scan, write_test_bag

    ros1 = rng.random() < 0.5
    f = factory_for(ros1=ros1)
    message = f.tf([(0, "map", "velodyne", np.eye(4))])
    transform = message.transforms[0].transform
    q = _quaternion(rng)
    transform.rotation.x, transform.rotation.y, transform.rotation.z, transform.rotation.w = q
    if rng.random() < 0.3:
        transform.translation.x = rng.choice(FLOATS)
    topic = rng.choice(["/tf", "/tf_static"])
    path = case / ("tf.bag" if ros1 else "tf")
    write_test_bag(
        path,
        [
            (topic, "tf2_msgs/msg/TFMessage", 0, message),
            ("/points", "sensor_msgs/msg/PointCloud2", 0, f.pointcloud2(0, "velodyne", scan())),
        ],
        ros1=ros1,
    )
    config = case / "tf.yaml"
    config.write_text("dataset:\n  poses: tf\n  map_frame: map\n")
    out = case / "out"
    argv = ["map", path, "--out", out, "-q", "--config", config] if rng.random() < 0.7 else ["inspect", path]
    return Made(
        f"{'ros1' if ros1 else 'ros2'} {topic} rotation {q}, translation x {transform.translation.x}", argv, out
    )


def _bag_file(copy: Path) -> Path:
    return next(iter(sorted(copy.glob("*.bag")) + sorted(copy.glob("*.mcap"))))


def _bag_argv(copy: Path, case: Path, rng: random.Random) -> tuple[list, Path | None]:
    bags = sorted(copy.glob("*.bag"))
    source = bags[0] if bags else copy  # a ROS 1 bag is a file, a ROS 2 bag its folder
    if rng.random() < 0.5:
        return ["inspect", source], None
    return ["map", source, "--out", case / "out", "-q"], case / "out"


def _truncated(seeds, copy: Path, case: Path, rng: random.Random) -> Made:
    bag = _bag_file(copy)
    data = bag.read_bytes()
    keep = rng.randrange(257) if rng.random() < 0.6 else rng.randrange(len(data))
    bag.write_bytes(data[:keep])
    argv, out = _bag_argv(copy, case, rng)
    return Made(f"{bag.name} cut at byte {keep} of {len(data)}", argv, out)


PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _png_header(width: int, height: int) -> bytes:
    import struct
    import zlib

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return PNG_SIGNATURE + struct.pack(">I", 13) + b"IHDR" + ihdr + struct.pack(">I", zlib.crc32(b"IHDR" + ihdr))


def _huge_image(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """`data` (a JPEG or PNG) declaring an extreme size: its own header's size patched, or the start
    replaced by a PNG header (same length: the data of a bag message keeps its size)."""
    size = rng.choice([(30000, 30000), (0, 0), (65535, 1), (1, 65535), (2**31 - 1, 2**31 - 1)])
    sof = data.find(b"\xff\xc0")
    if data.startswith(b"\xff\xd8") and sof > 0 and rng.random() < 0.5 and size[0] < 65536 and size[1] < 65536:
        patched = bytearray(data)
        patched[sof + 5 : sof + 9] = size[1].to_bytes(2, "big") + size[0].to_bytes(2, "big")
        return bytes(patched), f"JPEG header says {size[0]} x {size[1]}"
    header = _png_header(*size)
    return header + data[len(header) :], f"PNG header says {size[0]} x {size[1]}"


def _images_in_bag(seeds, copy: Path, case: Path, rng: random.Random) -> Made:
    bag = _bag_file(copy)
    data = bytearray(bag.read_bytes())
    starts = [m.start() for m in re.finditer(b"\xff\xd8\xff", data)]
    start = rng.choice(starts)
    end = data.find(b"\xff\xd9", start) + 2
    image, what = _huge_image(bytes(data[start:end]), rng)
    data[start:end] = image
    bag.write_bytes(bytes(data))
    argv, out = _bag_argv(copy, case, rng)
    return Made(f"{bag.name}: image at byte {start}: {what}", argv, out)


def _images_in_folder(seeds, copy: Path, case: Path, rng: random.Random) -> Made:
    images = sorted(p for p in copy.rglob("*") if p.suffix.lower() in (".png", ".jpg", ".jpeg"))
    victim = rng.choice(images)
    image, what = _huge_image(victim.read_bytes(), rng)
    victim.write_bytes(image)
    out = case / "out"
    argv = ["map", copy, "--out", out, "-q"] if rng.random() < 0.7 else ["inspect", copy]
    return Made(f"{victim.relative_to(copy)}: {what}", argv, out)


# --------------------------------------------------------------------------------- calibration
_NUMBER = re.compile(r"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")
CALIB_FILES = ("calib_*.txt", "calib.txt", "msmap_camera_config.yaml", "cameras.json", "terra_dataset.json")


def _calibration(seeds, copy: Path, case: Path, rng: random.Random) -> Made:
    files = sorted({p for pattern in CALIB_FILES for p in copy.rglob(pattern)})
    victim = rng.choice(files)
    text = victim.read_text()
    numbers = list(_NUMBER.finditer(text))
    value = rng.choice(["1e308", "-1e308", "1e309", "nan", "inf", "-inf", "1e-320", "9" * 400, "NaN", "-1"])
    edits = rng.sample(numbers, k=min(len(numbers), rng.choice([1, 1, 3])))
    for match in sorted(edits, key=lambda m: -m.start()):
        text = text[: match.start()] + value + text[match.end() :]
    victim.write_text(text)
    out = case / "out"
    argv = ["map", copy, "--out", out, "-q"] if rng.random() < 0.8 else ["inspect", copy]
    return Made(f"{victim.relative_to(copy)}: {len(edits)} numbers -> {value[:20]}", argv, out)


# -------------------------------------------------------------------------------------------- HTTP
def _escaped(obj: Any) -> bytes:
    """JSON bytes as a client sends them: lone surrogates escaped (\\ud800), which JSON allows."""
    return json.dumps(obj, ensure_ascii=True, allow_nan=True).encode()


def _http(seeds, copy: Path, case: Path, rng: random.Random) -> Made:
    from urllib.parse import quote

    kind = rng.randrange(6)
    if kind == 0:
        node = node_text(rng)
        return Made(f"GET /nodes/{node[:40]!r}", request=("GET", "/nodes/" + quote(node, safe=""), None))
    if kind == 1:
        x, y = number_text(rng), number_text(rng)
        path = f"/locate?x={quote(x)}&y={quote(y)}"
        return Made(f"GET /locate x={x[:30]!r} y={y[:30]!r}", request=("GET", path, None))
    if kind == 2:
        level, index = number_text(rng), number_text(rng)
        return Made(
            f"GET /regions/{level[:30]}/{index[:30]}", request=("GET", f"/regions/{quote(level)}/{quote(index)}", None)
        )
    query = query_text(rng)
    body: dict[str, Any] = {
        3: {"queries": [query]},
        4: {"queries": [query]},
        5: {"to": query, "from_node": rng.choice([0, 2**64, -1, 10**30, "²"])},
    }[kind]
    if kind == 3 and rng.random() < 0.5:
        body["alpha"] = rng.choice(FLOATS)
    if kind == 4 and rng.random() < 0.5:
        body["k"] = rng.choice([0, -1, 2**64, 10**400, 1e308, float("nan")])
    route = {3: "/find", 4: "/monitor", 5: "/plan"}[kind]
    return Made(f"POST {route} {json.dumps(body)[:80]}", request=("POST", route, _escaped(body)))


def families() -> list[Family]:
    return [
        Family("ids: node", "bundle", _node),
        Family("coordinates", "bundle", _coordinates),
        Family("queries", "bundle", _queries),
        Family("tf quaternions", "none", _tf_bag),
        Family("images: folder", "terra-folder", _images_in_folder),
        Family("images: bag", "rosbag2", _images_in_bag),
        Family("truncated: rosbag1", "rosbag1", _truncated),
        Family("truncated: rosbag2", "rosbag2", _truncated),
        Family("calibration: kitti-raw", "kitti-raw", _calibration),
        Family("calibration: semantickitti", "semantickitti", _calibration),
        Family("calibration: terra-folder", "terra-folder", _calibration),
        Family("http", "bundle", _http),
    ]


# ------------------------------------------------------------------------------------ running
def run_request(bundle: Path, request: tuple[str, str, bytes | None]) -> tuple[int, str]:
    """(status, body) of one request to a service over `bundle` (read-only, no token)."""
    from fastapi.testclient import TestClient

    from terra.loaded import LoadedBundle
    from terra.serve.app import create_app
    from terra.serve.config import ServeConfig

    method, path, body = request
    client = TestClient(create_app(LoadedBundle(bundle), settings=ServeConfig()), raise_server_exceptions=False)
    headers = {"Content-Type": "application/json"} if body is not None else {}
    response = client.request(method, path, content=body, headers=headers)
    return response.status_code, response.text


def judge_response(status: int, text: str) -> tuple[str, str]:
    """(outcome, detail) of an HTTP answer: 2xx with JSON is "ok", 4xx with a one-line JSON error is
    "refused"; a 5xx, a body that is not JSON or an error of several lines is a failure."""
    try:
        body = json.loads(text)
    except ValueError:
        return "traceback" if status >= 500 else "not one line", f"{status}: {text[:300]}"
    if status >= 500:
        return "traceback", f"{status}: {text[:300]}"
    if 400 <= status < 500:
        error = body.get("error") if isinstance(body, dict) else None
        if not isinstance(error, str) or "\n" in text or len(error) > 3000:
            return "not one line", f"{status}: {text[:300]}"
        return "refused", f"{status}: {error[:300]}"
    return "ok", ""


def copy_family_seed(family: Family, seeds, case: Path) -> Path:
    if family.seed == "none":
        (case / "data").mkdir()
        return case / "data"
    if family.seed == "bundle":
        return Path(shutil.copytree(seeds.bundle, case / "bundle"))
    source = seeds.datasets[family.seed]
    folder = source if source.is_dir() else source.parent
    return Path(shutil.copytree(folder, case / "data"))
