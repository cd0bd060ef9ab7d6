"""Opening ROS 1 and ROS 2 recordings through `rosbags` and reading their messages by time.

Accepted sources: a ROS 1 `.bag` file, a folder of ROS 1 `.bag` files (one recording split in
parts), a ROS 2 bag folder (metadata.yaml with sqlite3 `.db3` or `.mcap` storage), or a bare
`.mcap` / `.db3` file. Every failure of the underlying reader (truncated file, bad index, corrupt
chunk, unknown message type) becomes a TerraError naming the file.

Messages are addressed by (topic, log time in ns, ordinal among messages of that topic with the
same log time), which the reader can seek to, so a loader can index a bag once and then read any
message again without holding it in memory.
"""

from __future__ import annotations

import contextlib
import struct
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from terra.errors import TerraError

ROS2_SUFFIXES = (".mcap", ".db3")


def bag_paths(path: Path) -> list[Path]:
    """The files or folder `rosbags` opens for `path`; TerraError when it is no recording."""
    path = Path(path)
    if path.is_file() and path.suffix in (".bag", *ROS2_SUFFIXES):
        return [path]
    if path.is_dir():
        if (path / "metadata.yaml").is_file():
            return [path]
        bags = sorted(p for p in path.glob("*.bag") if p.is_file())  # never a FIFO: the reader would block
        if bags:
            return bags
    raise TerraError(
        f"{path}: not a ROS bag (expected a .bag or .mcap file, a ROS 2 bag folder with metadata.yaml, "
        "or a folder of .bag files)"
    )


def is_bag(path: Path) -> bool:
    """Cheap detection for `--format auto`."""
    try:
        bag_paths(path)
        return True
    except TerraError:
        return False


def recording_name(paths: list[Path]) -> str:
    """The recording's name: its (first) storage file's stem, e.g. `drive` for drive.bag,
    drive/drive_0.mcap or a folder holding drive.bag (a folder may be called anything)."""
    first = paths[0]
    if first.is_dir():
        files = sorted(p for p in first.iterdir() if p.suffix in ROS2_SUFFIXES)
        first = files[0] if files else first
    stem = first.stem
    return stem[:-2] if stem.endswith("_0") else stem


def storage_name(paths: list[Path]) -> str:
    """'rosbag1', 'rosbag2 (mcap)' or 'rosbag2 (sqlite3)'."""
    first = paths[0]
    if first.suffix == ".bag":
        return "rosbag1"
    if first.is_dir():
        text = check_ros2_folder(first)
        return "rosbag2 (mcap)" if "storage_identifier: mcap" in text else "rosbag2 (sqlite3)"
    return "rosbag2 (mcap)" if first.suffix == ".mcap" else "rosbag2 (sqlite3)"


def check_ros2_folder(folder: Path) -> str:
    """The text of a ROS 2 bag folder's metadata.yaml, after checking that every storage file it
    lists is a regular file inside the folder (the reader would block on a FIFO); TerraError otherwise."""
    from terra.fileio import decode_text, parse_yaml, read_bytes
    from terra.schemas import RosbagMetadata, validate_model

    path = folder / "metadata.yaml"
    text = decode_text(read_bytes(path, "bag metadata file", 16 << 20), path, "bag metadata file")
    info = validate_model(parse_yaml(text, path, "bag metadata file"), RosbagMetadata, path).rosbag2_bagfile_information
    for name in info.relative_file_paths + [f.path for f in info.files or []]:
        storage = folder / name
        if ".." in Path(name).parts or Path(name).is_absolute() or not storage.is_file():
            raise TerraError(f"{path}: lists storage file {name[:80]!r}, which is not a file in {folder}")
    return text


def _reader_errors() -> tuple[type[BaseException], ...]:
    from rosbags.highlevel import AnyReaderError
    from rosbags.rosbag1 import ReaderError as Reader1Error
    from rosbags.rosbag2 import ReaderError as Reader2Error
    from rosbags.serde import SerdeError
    from rosbags.typesys import TypesysError

    # Corrupt bytes surface from the decoders as these too (short reads, bad lengths, bad UTF-8).
    return (
        AnyReaderError,
        Reader1Error,
        Reader2Error,
        SerdeError,
        TypesysError,
        struct.error,
        EOFError,
        UnicodeDecodeError,
        OSError,
        IndexError,
        KeyError,
        ValueError,
        AssertionError,
        # A truncated mcap: rosbags' reader takes ord() of the empty read past the end of the file.
        TypeError,
        # A record or message length field that claims more bytes than any bag holds: the reader
        # asks for a buffer of that size before it finds the data short.
        MemoryError,
        OverflowError,
        RecursionError,
    )


@contextmanager
def bag_errors(where: str) -> Iterator[None]:
    """Turn a reader failure into one TerraError line naming `where`."""
    try:
        yield
    except TerraError:
        raise
    except _reader_errors() as exc:
        reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise TerraError(f"{where}: unreadable bag ({reason}); is it truncated or corrupt?") from None


@dataclass(frozen=True)
class TopicSummary:
    """A topic of the recording: message type (ROS 2 spelling, e.g. sensor_msgs/msg/Image) and count."""

    name: str
    msgtype: str
    count: int


def header_stamp(raw: bytes | memoryview, ros2: bool) -> float:
    """std_msgs/Header stamp (seconds) of a serialized message that starts with a header, read
    from the wire bytes without deserializing the rest: ROS 1 is little-endian [seq u32, sec u32,
    nsec u32, ...]; ROS 2 CDR has a 4-byte encapsulation header (byte 1: 1 little, 0 big endian)
    before [sec i32, nanosec u32, ...]."""
    if ros2:
        order = "<" if raw[1] & 1 else ">"
        sec, nsec = struct.unpack_from(order + "iI", raw, 4)
    else:
        sec, nsec = struct.unpack_from("<II", raw, 4)
    return sec + nsec * 1e-9


class Bag:
    """An open recording. `read` streams raw messages in log-time order; `fetch` seeks to some."""

    def __init__(self, path: Path) -> None:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore

        self.path = Path(path)
        self.paths = bag_paths(self.path)
        self.storage = storage_name(self.paths)
        with bag_errors(str(self.path)):
            self.reader = AnyReader(self.paths, default_typestore=get_typestore(Stores.ROS2_HUMBLE))
            self.reader.open()
        self.ros2 = bool(self.reader.is2)
        self._connections: dict[str, list] = {}
        for conn in self.reader.connections:
            self._connections.setdefault(conn.topic, []).append(conn)
        with bag_errors(str(self.path)):
            self.topics = {
                name: TopicSummary(name, info.msgtype or "?", int(info.msgcount))
                for name, info in sorted(self.reader.topics.items())
            }
            self.start_ns, self.end_ns = int(self.reader.start_time), int(self.reader.end_time)

    def close(self) -> None:
        """Close the recording's files; again is harmless."""
        reader = getattr(self, "reader", None)
        if reader is not None and reader.stack is not None:
            reader.close()

    def __del__(self) -> None:
        # Datasets are handed around without a with-block (mapping, evaluation, Dask workers), so
        # a dropped one closes its files here rather than leaving them to the garbage collector.
        with contextlib.suppress(Exception):  # interpreter shutdown: nothing left to report to
            self.close()

    def topics_of_type(self, *msgtypes: str) -> list[str]:
        """Topics whose message type is one of `msgtypes` (ROS 2 spelling), sorted."""
        return [t.name for t in self.topics.values() if t.msgtype in msgtypes]

    def require(self, topic: str, msgtypes: tuple[str, ...], role: str) -> str:
        """`topic` if it exists with one of `msgtypes`; TerraError listing the candidates otherwise."""
        have = self.topics.get(topic)
        candidates = self.topics_of_type(*msgtypes)
        short = " or ".join(m.replace("/msg/", "/") for m in msgtypes)
        if have is None:
            listed = (
                ", ".join(candidates)
                if candidates
                else f"none of type {short}; topics: {', '.join(self.topics) or 'none'}"
            )
            raise TerraError(f"{self.path}: no topic '{topic}' for the {role}; {short} topics: {listed}")
        if have.msgtype not in msgtypes:
            raise TerraError(
                f"{self.path}: topic '{topic}' ({role}) has type {have.msgtype}, expected {short}; "
                f"{short} topics: {', '.join(candidates) or 'none'}"
            )
        return topic

    def read(
        self, topics: list[str], start_ns: int | None = None, stop_ns: int | None = None
    ) -> Iterator[tuple[str, int, bytes]]:
        """(topic, log time ns, raw bytes) of every message of `topics` in [start_ns, stop_ns)."""
        connections = [c for t in topics for c in self._connections.get(t, [])]
        if not connections:
            return
        with bag_errors(str(self.path)):
            for conn, log_ns, raw in self.reader.messages(connections=connections, start=start_ns, stop=stop_ns):
                yield conn.topic, int(log_ns), raw

    def fetch(self, wanted: list[tuple[str, int, int]]) -> dict[tuple[str, int, int], bytes]:
        """Raw bytes of the messages addressed as (topic, log ns, ordinal), read in one pass over
        the time span they cover. Missing ones are absent from the result."""
        if not wanted:
            return {}
        topics = sorted({w[0] for w in wanted})
        want = set(wanted)
        lo, hi = min(w[1] for w in wanted), max(w[1] for w in wanted) + 1
        seen: dict[tuple[str, int], int] = {}
        out: dict[tuple[str, int, int], bytes] = {}
        for topic, log_ns, raw in self.read(topics, lo, hi):
            ordinal = seen.get((topic, log_ns), 0)
            seen[(topic, log_ns)] = ordinal + 1
            if (topic, log_ns, ordinal) in want:
                out[(topic, log_ns, ordinal)] = raw
                if len(out) == len(want):
                    break
        return out

    def deserialize(self, raw: bytes, topic: str, where: str | None = None) -> Any:
        """The message object of `raw` (a message of `topic`): a dataclass rosbags generates from the
        bag's own message definitions, so its fields are known only when the bag is read."""
        msgtype = self.topics[topic].msgtype
        with bag_errors(where or f"{self.path} {topic}"):
            return self.reader.deserialize(raw, msgtype)


def message_bytes(data: object, where: str, field: str = "data") -> np.ndarray:
    """A message's `uint8[]` field as a flat uint8 array, whatever holds it: a NumPy array (rosbags),
    bytes, an array.array or a memoryview (rclpy), or a list of ints; TerraError naming the field
    for anything else (a list with values outside 0..255, text)."""
    if isinstance(data, np.ndarray):
        return data.reshape(-1).view(np.uint8) if data.dtype.itemsize == 1 else data.view(np.uint8).reshape(-1)
    if isinstance(data, list | tuple):
        values = np.asarray(data)
        if values.size and (not np.issubdtype(values.dtype, np.integer) or values.min() < 0 or values.max() > 255):
            raise TerraError(f"{where}: field '{field}' must hold bytes (integers 0..255)")
        return values.astype(np.uint8).reshape(-1)
    try:
        return np.frombuffer(data, np.uint8)  # type: ignore[arg-type]  # bytes, bytearray, array.array, memoryview
    except TypeError:
        raise TerraError(f"{where}: field '{field}' must hold bytes, got {type(data).__name__}") from None


def stamps_seconds(msg_stamp) -> float:
    """builtin_interfaces/Time (sec, nanosec) as float seconds."""
    return int(msg_stamp.sec) + int(msg_stamp.nanosec) * 1e-9


MAX_TRANSLATION = 1.0e7  # metres: farther is a corrupt message, and would overflow later arithmetic
MAX_QUATERNION_LENGTH = 1.0e6  # a unit quaternion written by a driver is within 1e-3 of length 1


def xyz_quat_of(transform, where: str = "transform") -> np.ndarray:
    """[tx, ty, tz, qx, qy, qz, qw] of a geometry_msgs/Transform or Pose; TerraError naming `where`
    for non-finite values, a translation beyond MAX_TRANSLATION or a quaternion of (near) zero
    length, which is no rotation at all, or of a length past MAX_QUATERNION_LENGTH."""
    t = getattr(transform, "translation", None) or transform.position
    q = getattr(transform, "rotation", None) or transform.orientation
    values = np.array([t.x, t.y, t.z, q.x, q.y, q.z, q.w], float)
    if not np.isfinite(values).all() or np.abs(values[:3]).max() > MAX_TRANSLATION:
        raise TerraError(f"{where}: translation and rotation must be finite (within {MAX_TRANSLATION:g} m)")
    norm = float(np.linalg.norm(values[3:]))
    if norm < 1e-6:
        raise TerraError(f"{where}: rotation quaternion has zero length (x, y, z, w all 0); expected a unit quaternion")
    if norm > MAX_QUATERNION_LENGTH:  # components past 1e154 overflow its length to infinity
        raise TerraError(f"{where}: rotation quaternion has length {norm:.3g}; expected a unit quaternion")
    return values  # not normalised here: the rotation code does it, and the same bytes give the same map
