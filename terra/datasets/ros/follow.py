"""Reading a ROS bag while it is being recorded (`terra map SOURCE --follow`).

A recorder appends to its storage file and writes the index only when it closes the bag (the mcap
summary and footer; rosbag2's metadata.yaml; a ROS 1 bag's index and its position in the bag
header), so the readers of terra/datasets/ros/bag.py, which
need that index, cannot open it yet. `GrowingBag` reads the file's complete records as they
appear instead: each poll parses only the bytes added since the last one and remembers where each
message is (not the message); `IndexBuilder` keeps the bag's index up to date message by message.
`FollowedBag` is the frame source over it: at each poll the frames are paired again exactly as
`RosbagDataset` pairs them (so the final frames are those of the finished bag), and a frame is
handed on once it is complete: the recording has gone `settle` seconds past the time its image
and its pose could still arrive (`max_gap`, `max_pose_gap` of the dataset section).

Storage: an mcap file (chunks uncompressed, or zstd / lz4 compressed), a sqlite3 `.db3` file
(read-only, the committed messages), or a ROS 1 `.bag` (`.bag.active` while `rosbag record`
writes it; chunks uncompressed, bz2 or lz4). The recording ends when the writer closes it (mcap:
its data-end record; ROS 1: the index position written; ROS 2 folders: metadata.yaml written),
when the file has not grown for `idle` seconds, or on Ctrl-C while waiting. Messages are indexed
in the order the file holds them, which is log-time order for the recorders; a split recording
(several storage files) is refused.
"""

from __future__ import annotations

import os
import sqlite3
import struct
import time
from array import array
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from terra.datasets.base import ClassTable, Frame, SemanticClass
from terra.datasets.folder_io import read_classes
from terra.datasets.ros.bag import ROS2_SUFFIXES, Bag, TopicSummary, bag_errors
from terra.datasets.ros.index import TF_TOPICS, BagIndex, IndexBuilder
from terra.datasets.ros.topics import CLOUD, IMAGE, ODOMETRY
from terra.datasets.rosbag import RosbagConfig, RosbagDataset
from terra.errors import TerraError

MCAP_MAGIC = b"\x89MCAP0\r\n"


def storage_file(path: Path) -> Path | None:
    """The file a recording is written to: `path` itself (.mcap, .db3, a ROS 1 .bag or .bag.active),
    or the one storage file in the ROS 2 bag folder `path`; None while the recorder has not created
    it yet. TerraError for another file or a folder split into several files."""
    path = Path(path)
    ros1 = path.suffix == ".bag" or path.name.endswith(".bag.active")
    if path.is_file():
        if path.suffix not in ROS2_SUFFIXES and not ros1:
            raise TerraError(f"{path}: not a bag being recorded (expected .mcap, .db3, .bag or .bag.active)")
        return path
    if ros1 or not path.is_dir():
        return None
    files = sorted(p for p in path.iterdir() if p.suffix in ROS2_SUFFIXES and p.is_file())
    if len(files) > 1:
        raise TerraError(f"{path}: the recording is split into {len(files)} files; --follow reads one storage file")
    return files[0] if files else None


def is_recording(path: Path) -> bool:
    """Whether `terra map --follow` reads `path` as a recording: a .mcap, .db3 or .bag file, or a
    folder holding a ROS 2 storage file or nothing yet (the recorder is about to start)."""
    path = Path(path)
    if path.suffix in (*ROS2_SUFFIXES, ".bag") or path.name.endswith(".bag.active"):
        return True
    return path.is_dir() and (not any(path.iterdir()) or any(p.suffix in ROS2_SUFFIXES for p in path.iterdir()))


def recording_closed(path: Path) -> bool:
    """Whether the recorder has closed the ROS 2 bag folder `path` (it writes metadata.yaml last)."""
    return Path(path).is_dir() and (Path(path) / "metadata.yaml").is_file()


class _Storage:
    """Complete records of one growing storage file: messages as (topic id, log ns, location)."""

    ended = False  # the writer closed the file (its end record read)

    def poll(self) -> list[tuple[int, int, Any]]:
        """Messages that became complete since the last poll: (channel id, log ns, location)."""
        raise NotImplementedError

    def raw(self, location: Any) -> bytes:
        raise NotImplementedError

    def size(self) -> int:
        raise NotImplementedError

    def close(self) -> None:
        raise NotImplementedError


class _Mcap(_Storage):
    """An mcap file read record by record from where the last poll stopped (top-level messages,
    chunks and, inside chunks, schemas, channels and messages; the summary is not needed)."""

    def __init__(self, path: Path, on_schema: Callable, on_channel: Callable) -> None:
        self.path = path
        self.fd = os.open(path, os.O_RDONLY)
        self.offset = 0
        self.on_schema, self.on_channel = on_schema, on_channel
        self.schema_names: dict[int, str] = {}
        self.chunks: list[tuple[int, int, str, int]] = []  # compressed chunks: (offset, size, codec, raw size)
        self._cache: tuple[int, bytes] | None = None

    def size(self) -> int:
        return os.fstat(self.fd).st_size

    def close(self) -> None:
        os.close(self.fd)

    def poll(self) -> list[tuple[int, int, Any]]:
        size, found = self.size(), []
        if self.offset == 0:
            if size < len(MCAP_MAGIC):
                return found
            if os.pread(self.fd, len(MCAP_MAGIC), 0) != MCAP_MAGIC:
                raise TerraError(f"{self.path}: not an mcap file (its first bytes are not the mcap magic)")
            self.offset = len(MCAP_MAGIC)
        while not self.ended and size - self.offset >= 9:
            op, length = struct.unpack("<BQ", os.pread(self.fd, 9, self.offset))
            start = self.offset + 9
            if start + length > size:
                break  # the writer is still writing this record
            if op == 0x01:
                profile = _string(os.pread(self.fd, min(length, 1 << 16), start), 0)[0]
                if profile != "ros2":
                    raise TerraError(f"{self.path}: mcap profile {profile!r}; expected a ROS 2 recording (ros2)")
            elif op in (0x03, 0x04, 0x05):
                self._record(op, os.pread(self.fd, length, start), found, -1, start)
            elif op == 0x06:
                self._chunk(os.pread(self.fd, length, start), start, found)
            elif op in (0x0F, 0x02):  # data end, footer: the writer closed the file
                self.ended = True
            self.offset = start + length
        return found

    def _chunk(self, content: bytes, start: int, found: list) -> None:
        """The records of a chunk: located in the file when it is stored uncompressed, else in the
        chunk's decompressed bytes (decompressed again, one chunk cached, when a message is read)."""
        raw_size = struct.unpack_from("<Q", content, 16)[0]
        codec, at = _string(content, 28)
        size = struct.unpack_from("<Q", content, at)[0]
        at += 8
        if codec:
            self.chunks.append((start + at, size, codec, raw_size))
            records, chunk, base = (
                self._decompress(len(self.chunks) - 1, content[at : at + size]),
                len(self.chunks) - 1,
                0,
            )
        else:
            records, chunk, base = content[at : at + size], -1, start + at
        pos = 0
        while pos + 9 <= len(records):
            op, length = struct.unpack_from("<BQ", records, pos)
            self._record(op, records[pos + 9 : pos + 9 + length], found, chunk, base + pos + 9)
            pos += 9 + length

    def _decompress(self, chunk: int, data: bytes) -> bytes:
        from rosbags.rosbag2.storage_mcap import decompress

        _, _, codec, raw_size = self.chunks[chunk]
        with bag_errors(f"{self.path} chunk {chunk}"):
            records = decompress(data, codec, raw_size, 0)
        self._cache = (chunk, records)
        return records

    def _record(self, op: int, content: bytes, found: list, chunk: int, offset: int) -> None:
        if op == 0x03:
            key = struct.unpack_from("<H", content, 0)[0]
            name, at = _string(content, 2)
            encoding, at = _string(content, at)
            data, _ = _string(content, at)
            self.schema_names[key] = name
            self.on_schema(name, encoding, data)
        elif op == 0x04:
            key, schema = struct.unpack_from("<HH", content, 0)
            topic, _ = _string(content, 4)
            self.on_channel(key, self.schema_names.get(schema, ""), topic)
        elif op == 0x05:
            channel, _, log_ns = struct.unpack_from("<HIQ", content, 0)
            found.append((channel, log_ns, (chunk, offset + 22, len(content) - 22)))

    def raw(self, location: Any) -> bytes:
        chunk, offset, length = location
        if chunk < 0:
            return os.pread(self.fd, length, offset)
        if self._cache is None or self._cache[0] != chunk:
            start, size, _, _ = self.chunks[chunk]
            self._decompress(chunk, os.pread(self.fd, size, start))
        assert self._cache is not None
        return self._cache[1][offset : offset + length]


def _string(content: bytes, at: int) -> tuple[str, int]:
    """An mcap string (uint32 length, UTF-8 bytes) at byte `at`, and the byte after it."""
    (length,) = struct.unpack_from("<I", content, at)
    return bytes(content[at + 4 : at + 4 + length]).decode(), at + 4 + length


class _Sqlite(_Storage):
    """A rosbag2 sqlite3 file, opened read-only: the messages committed since the last poll."""

    def __init__(self, path: Path, on_schema: Callable, on_channel: Callable) -> None:
        self.path = path
        self.db = sqlite3.connect(f"file:{path}?mode=ro", uri=True, check_same_thread=False)
        self.on_schema, self.on_channel = on_schema, on_channel
        self.last_id = 0
        self.types: set[str] = set()
        self.topics: set[int] = set()

    def size(self) -> int:
        wal = self.path.with_name(self.path.name + "-wal")
        return self.path.stat().st_size + (wal.stat().st_size if wal.is_file() else 0)

    def close(self) -> None:
        self.db.close()

    def poll(self) -> list[tuple[int, int, Any]]:
        try:
            return self._poll()
        except sqlite3.OperationalError as exc:
            if "locked" in str(exc) or "no such table" in str(exc):
                return []  # the writer is committing, or has not created its tables yet
            raise TerraError(f"{self.path}: unreadable bag ({exc})") from None
        except sqlite3.DatabaseError as exc:
            raise TerraError(f"{self.path}: unreadable bag ({exc}); is it truncated or corrupt?") from None

    def _poll(self) -> list[tuple[int, int, Any]]:
        db = self.db
        tables = {row[0] for row in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        if "message_definitions" in tables:
            for msgtype, encoding, data in db.execute(
                "SELECT topic_type, encoding, encoded_message_definition FROM message_definitions"
            ):
                if msgtype not in self.types:
                    self.types.add(msgtype)
                    self.on_schema(msgtype, encoding, data)
        for key, topic, msgtype in db.execute("SELECT id, name, type FROM topics ORDER BY id"):
            if key not in self.topics:
                self.topics.add(key)
                self.on_channel(key, msgtype, topic)
        rows = db.execute(
            "SELECT id, topic_id, timestamp FROM messages WHERE id > ? ORDER BY id", (self.last_id,)
        ).fetchall()
        if rows:
            self.last_id = int(rows[-1][0])
        return [(int(topic), int(ns), int(key)) for key, topic, ns in rows]

    def raw(self, location: Any) -> bytes:
        row = self.db.execute("SELECT data FROM messages WHERE id = ?", (int(location),)).fetchone()
        if row is None:
            raise TerraError(f"{self.path}: message {location} is gone from the bag")
        return bytes(row[0])


class _Ros1(_Storage):
    """A ROS 1 bag being written, record by record: chunks (none, bz2 or lz4) holding connection
    and message records. The writer closes it by writing the index and its position into the bag
    header (until then 0); the records from there on are the index, not data."""

    def __init__(self, path: Path, on_schema: Callable, on_channel: Callable) -> None:
        self.path, self.on_schema, self.on_channel = path, on_schema, on_channel
        self.fd = os.open(path, os.O_RDONLY)
        self.offset = 0
        self.chunks: list[tuple[int, int, str]] = []  # compressed chunks: (offset, size, codec)
        self._cache: tuple[int, bytes] | None = None

    def size(self) -> int:
        return os.fstat(self.fd).st_size

    def close(self) -> None:
        os.close(self.fd)

    def poll(self) -> list[tuple[int, int, Any]]:
        size, found = self.size(), []
        if self.offset == 0:
            if size < 13:
                return found
            if os.pread(self.fd, 13, 0) != b"#ROSBAG V2.0\n":
                raise TerraError(f"{self.path}: not a ROS 1 bag (its first bytes are not #ROSBAG V2.0)")
            self.offset = 13
        index_pos = self._index_pos(size)
        end = index_pos if index_pos else size
        while self.offset < end:
            record = self._read_record(self.offset, end)
            if record is None:
                break  # the writer is still writing this record
            fields, data_at, data_len = record
            if fields.get("op") == b"\x05":
                self._chunk(fields, data_at, data_len, found)
            self.offset = data_at + data_len
        self.ended = bool(index_pos) and self.offset >= index_pos
        return found

    def _index_pos(self, size: int) -> int:
        """Where the index starts, from the bag header (0 while the writer has not closed the bag)."""
        record = self._read_record(13, size)
        if record is None or record[0].get("op") != b"\x03":
            return 0
        return struct.unpack("<Q", record[0].get("index_pos", bytes(8)))[0]

    def _read_record(self, at: int, end: int) -> tuple[dict[str, bytes], int, int] | None:
        """(header fields, data offset, data length) of the record at `at`, None when incomplete."""
        if at + 4 > end:
            return None
        (header_len,) = struct.unpack("<I", os.pread(self.fd, 4, at))
        if at + 8 + header_len > end:
            return None
        header = os.pread(self.fd, header_len + 4, at + 4)
        (data_len,) = struct.unpack_from("<I", header, header_len)
        if at + 8 + header_len + data_len > end:
            return None
        return _ros1_fields(header[:header_len]), at + 8 + header_len, data_len

    def _chunk(self, fields: dict[str, bytes], data_at: int, data_len: int, found: list) -> None:
        codec = fields.get("compression", b"none").decode()
        data = os.pread(self.fd, data_len, data_at)
        if codec == "none":
            records, chunk, base = data, -1, data_at
        else:
            self.chunks.append((data_at, data_len, codec))
            chunk, base = len(self.chunks) - 1, 0
            records = self._decompress(chunk, data)
        pos = 0
        while pos + 4 <= len(records):
            (header_len,) = struct.unpack_from("<I", records, pos)
            header = _ros1_fields(records[pos + 4 : pos + 4 + header_len])
            (length,) = struct.unpack_from("<I", records, pos + 4 + header_len)
            body = pos + 8 + header_len
            op = header.get("op")
            if op == b"\x07":
                self._connection(header, records[body : body + length])
            elif op == b"\x02":
                conn = struct.unpack("<I", header["conn"])[0]
                sec, nsec = struct.unpack("<II", header["time"])
                found.append((conn, sec * 1_000_000_000 + nsec, (chunk, base + body, length)))
            pos = body + length

    def _connection(self, header: dict[str, bytes], body: bytes) -> None:
        from rosbags.typesys.msg import normalize_msgtype

        info = _ros1_fields(body)
        msgtype = normalize_msgtype(info.get("type", b"").decode())
        self.on_schema(msgtype, "ros1msg", info.get("message_definition", b"").decode())
        self.on_channel(struct.unpack("<I", header["conn"])[0], msgtype, header["topic"].decode())

    def _decompress(self, chunk: int, data: bytes) -> bytes:
        import bz2

        from lz4.frame import decompress as lz4_decompress  # type: ignore[import-untyped]

        codec = self.chunks[chunk][2]
        if codec not in ("bz2", "lz4"):
            raise TerraError(f"{self.path}: chunk compression {codec!r}; expected none, bz2 or lz4")
        with bag_errors(f"{self.path} chunk {chunk}"):
            records = bz2.decompress(data) if codec == "bz2" else lz4_decompress(data)
        self._cache = (chunk, records)
        return records

    def raw(self, location: Any) -> bytes:
        chunk, offset, length = location
        if chunk < 0:
            return os.pread(self.fd, length, offset)
        if self._cache is None or self._cache[0] != chunk:
            start, size, _ = self.chunks[chunk]
            self._decompress(chunk, os.pread(self.fd, size, start))
        assert self._cache is not None
        return self._cache[1][offset : offset + length]


def _ros1_fields(header: bytes) -> dict[str, bytes]:
    """The name=value fields of a ROS 1 record header (each: uint32 length, then the bytes)."""
    fields, pos = {}, 0
    while pos + 4 <= len(header):
        (length,) = struct.unpack_from("<I", header, pos)
        name, _, value = bytes(header[pos + 4 : pos + 4 + length]).partition(b"=")
        fields[name.decode(errors="replace")] = value
        pos += 4 + length
    return fields


class GrowingBag(Bag):
    """A storage file being recorded (ROS 2 mcap or sqlite3, ROS 1), read as far as it is complete.
    It stands in for `Bag` (the same topics, read, fetch and deserialize) so `RosbagDataset` pairs
    its frames; `poll()` takes in what the writer added since the last poll."""

    def __init__(self, path: Path, storage: Path) -> None:
        from rosbags.typesys import Stores, get_typestore

        self.path, self.file, self.paths = Path(path), Path(storage), [Path(storage)]
        ros1 = self.file.suffix == ".bag" or self.file.name.endswith(".bag.active")
        self.storage = "rosbag1" if ros1 else "rosbag2 (mcap)" if self.file.suffix == ".mcap" else "rosbag2 (sqlite3)"
        self.ros2 = not ros1
        self.reader = None
        # The bag's own message definitions, as rosbags' AnyReader uses them; Humble's for the rest.
        self.store, self.fallback = get_typestore(Stores.EMPTY), get_typestore(Stores.ROS2_HUMBLE)
        self.channels: dict[int, tuple[str, str]] = {}  # channel id -> (topic, message type)
        self.counts: dict[str, int] = {}
        self.topics: dict[str, TopicSummary] = {}
        self.log_ns = array("q")
        self.topic_of: list[str] = []
        self.locations: list[Any] = []
        self.by_key: dict[tuple[str, int], list[int]] = {}
        self.start_ns, self.end_ns = 0, 0
        self._order: np.ndarray | None = None
        opener = _Ros1 if ros1 else _Mcap if self.file.suffix == ".mcap" else _Sqlite
        with bag_errors(str(self.file)):
            self.io: _Storage = opener(self.file, self._schema, self._channel)

    @property
    def ended(self) -> bool:
        """Whether the writer closed the file (mcap: its data-end record was read)."""
        return self.io.ended

    def size(self) -> int:
        """Bytes the storage holds now (it grows while the recording goes on)."""
        return self.io.size()

    def close(self) -> None:
        io = getattr(self, "io", None)
        if io is not None:
            self.io = None  # type: ignore[assignment]
            io.close()

    def _schema(self, msgtype: str, encoding: str, data: str) -> None:
        from rosbags.typesys import get_types_from_idl, get_types_from_msg

        if not data or msgtype in self.store.types:
            return
        with bag_errors(f"{self.file} message definition of {msgtype}"):
            if encoding == "ros2idl":
                separator = "=" * 80 + "\n"
                parts = [part.split("\n", 1)[1] for part in data.split(separator)[1:]] or [data]
                types = {}
                for idl in parts:
                    types.update(get_types_from_idl(idl))
            else:
                types = get_types_from_msg(data, msgtype)
            self.store.register(types)

    def _channel(self, key: int, msgtype: str, topic: str) -> None:
        self.channels[key] = (topic, msgtype)
        self.counts.setdefault(topic, 0)
        self.topics[topic] = TopicSummary(topic, msgtype or "?", self.counts[topic])

    def poll(self) -> int:
        """Take in the messages completed since the last poll; how many there were."""
        with bag_errors(str(self.file)):
            found = self.io.poll()
        for channel, log_ns, location in found:
            topic = self.channels.get(channel, (None,))[0]
            if topic is None:
                continue  # a message of no announced channel: a reader could not decode it either
            self.by_key.setdefault((topic, log_ns), []).append(len(self.locations))
            self.log_ns.append(log_ns)
            self.topic_of.append(topic)
            self.locations.append(location)
            self.counts[topic] += 1
            self.start_ns = log_ns if len(self.locations) == 1 else min(self.start_ns, log_ns)
            self.end_ns = max(self.end_ns, log_ns)
        for topic, (name, msgtype, _) in {t: (s.name, s.msgtype, s.count) for t, s in self.topics.items()}.items():
            self.topics[topic] = TopicSummary(name, msgtype, self.counts[topic])
        if found:
            self._order = None
        return len(found)

    def messages(self) -> Iterator[tuple[str, int, bytes]]:
        """(topic, log ns, raw) of every message taken in so far, in file order (`poll` order)."""
        for k in range(len(self.locations)):
            yield self.topic_of[k], int(self.log_ns[k]), self.io.raw(self.locations[k])

    def read(
        self, topics: list[str], start_ns: int | None = None, stop_ns: int | None = None
    ) -> Iterator[tuple[str, int, bytes]]:
        if self._order is None:
            self._order = np.argsort(np.frombuffer(self.log_ns, np.int64), kind="stable")
        wanted = set(topics)
        lo, hi = start_ns if start_ns is not None else -(2**63), stop_ns if stop_ns is not None else 2**63
        for k in self._order:
            log_ns = self.log_ns[k]
            if self.topic_of[k] in wanted and lo <= log_ns < hi:
                with bag_errors(str(self.file)):
                    raw = self.io.raw(self.locations[k])
                yield self.topic_of[k], int(log_ns), raw

    def fetch(self, wanted: list[tuple[str, int, int]]) -> dict[tuple[str, int, int], bytes]:
        out = {}
        for topic, log_ns, ordinal in wanted:
            found = self.by_key.get((topic, log_ns), [])
            if ordinal < len(found):
                with bag_errors(str(self.file)):
                    out[(topic, log_ns, ordinal)] = self.io.raw(self.locations[found[ordinal]])
        return out

    def deserialize(self, raw: bytes, topic: str, where: str | None = None) -> Any:
        msgtype = self.topics[topic].msgtype
        store = self.store if msgtype in self.store.types else self.fallback
        with bag_errors(where or f"{self.file} {topic}"):
            return store.deserialize_cdr(raw, msgtype) if self.ros2 else store.deserialize_ros1(raw, msgtype)


class _FollowDataset(RosbagDataset):
    """The frames of a growing bag as far as it is recorded, paired exactly as `RosbagDataset`
    pairs the finished bag's, over the index kept up to date by `builder`."""

    def __init__(self, bag: GrowingBag, builder: IndexBuilder, config: RosbagConfig, root: Path, name: str) -> None:
        self.path, self.config, self.root, self.name = bag.path, config, root, name
        self.classes = read_classes(root) or ClassTable([SemanticClass(0, "unlabeled")])
        self.skipped, self.skipped_notes = {}, {}
        self._pose_lookup = None
        self.bag, self._builder = bag, builder
        self._open(config, False)

    def _index(self, stamped: list[str], odom_topic: str | None, show_progress: bool) -> BagIndex:
        if odom_topic is not None and odom_topic != self._builder.odometry_topic:
            raise TerraError(f"{self.path}: odometry topic {odom_topic} appeared after another one was followed")
        return self._builder.result()

    def close(self) -> None:
        """The growing bag stays open: it belongs to the FollowedBag."""

    def __del__(self) -> None:
        pass

    def refs(self) -> list[tuple[float, tuple, np.ndarray]]:
        """(stamp, cloud message key, T_map_lidar) of every frame, in order."""
        return [(ref.stamp, ref.cloud, ref.T_map_lidar) for ref in self._frames]


class FollowedBag:
    """A `FrameSource` over a ROS recording still being written (see the module docstring).

    path: the ROS 2 bag folder, its .mcap / .db3 file, or a ROS 1 .bag / .bag.active file.
    config: the `dataset` section (topics, frames,
    max_gap, max_pose_gap). idle: seconds without growth after which the recording counts as
    ended (None: wait until the writer closes it, or the iterator is closed). poll: seconds between
    looks at the file. settle: seconds the recording must go past a frame's latest possible image
    and pose before the frame is handed on. on_wait: called at each poll that found nothing new.
    After `frames()` ends, `ended_by` says why: 'closed' (the mcap's end record), 'metadata.yaml',
    'idle' or 'interrupted' (Ctrl-C while waiting)."""

    def __init__(
        self,
        path: Path,
        config: RosbagConfig | None = None,
        idle: float | None = None,
        poll: float = 0.5,
        settle: float = 1.0,
        on_wait: Callable[[], None] | None = None,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        self.path = Path(path)
        self.config = config or RosbagConfig()
        if self.config.poses == "odometry":
            raise TerraError(f"{self.path}: --follow needs the recording's own poses (dataset.poses tf, topic or auto)")
        self.idle, self.poll, self.settle, self.on_wait = idle, poll, settle, on_wait
        self.clock, self.sleep = clock, sleep
        self.root = self.path if self.path.is_dir() else self.path.parent
        self.classes = read_classes(self.root) or ClassTable([SemanticClass(0, "unlabeled")])
        file = storage_file(self.path)
        self.name = _recording_stem(file) if file is not None else self.path.stem
        self.ended_by: str | None = None
        self.bag: GrowingBag | None = None
        self.builder: IndexBuilder | None = None
        self.dataset: _FollowDataset | None = None
        self.last_growth = clock()
        self._size = -1
        self._unpaired, self._paired_at, self._pair_cost = 0, 0.0, 0.0

    @property
    def horizon(self) -> float:
        """Seconds of recording after a scan within which its image and pose may still arrive."""
        return max(self.config.max_gap, self.config.max_pose_gap) + self.settle

    def frames(self) -> Iterator[Frame]:
        fused: list[tuple[float, tuple, np.ndarray]] = []
        try:
            while True:
                ended, taken = self._look()
                dataset = self._pair_again(ended, taken)
                if dataset is not None:
                    refs = dataset.refs()
                    _check_prefix(self.path, refs, fused)
                    stop = len(refs) if ended else self._settled(refs)
                    for i in range(len(fused), stop):
                        yield dataset[i]
                        fused.append(refs[i])
                if ended:
                    return
                if self._size_unchanged() and not self._wait():
                    self.ended_by = "interrupted"
                    return
        finally:
            if self.bag is not None:
                self.bag.close()

    def _wait(self) -> bool:
        """Let the consumer act (`on_wait`), then sleep one poll; False on Ctrl-C meanwhile: the
        recording is then over for this run, and what was handed on stays whole."""
        try:
            if self.on_wait is not None:
                self.on_wait()
            self.sleep(self.poll)
        except KeyboardInterrupt:
            return False
        return True

    def waiting_for(self) -> float:
        """Seconds since the recording last grew."""
        return self.clock() - self.last_growth

    # -- private ------------------------------------------------------------------------------

    def _look(self) -> tuple[bool, int]:
        """Take in what the writer added: whether the recording has ended, and how many messages came."""
        closed = recording_closed(self.path)  # read before the file: metadata.yaml comes last
        if self.bag is None:
            file = storage_file(self.path)
            if file is not None:
                self.name = _recording_stem(file)
                self.bag = GrowingBag(self.path, file)
                self.builder = IndexBuilder(self.bag, [], self.config.odometry_topic)
        taken = 0
        if self.bag is not None:
            before = len(self.bag.locations)
            self.bag.poll()
            self._index(before)
            taken = len(self.bag.locations) - before
        if self.bag is not None and self.bag.ended:
            self.ended_by = "closed"
        elif closed and self.bag is not None:
            self.ended_by = "metadata.yaml"
        elif self.idle is not None and self.waiting_for() >= self.idle:
            self.ended_by = "idle"
        return self.ended_by is not None, taken

    def _index(self, before: int) -> None:
        bag, builder = self.bag, self.builder
        assert bag is not None and builder is not None
        for k in range(before, len(bag.locations)):
            topic = bag.topic_of[k]
            msgtype = bag.topics[topic].msgtype
            if topic not in builder.rows and msgtype in CLOUD + IMAGE:
                builder.track(topic)
            elif msgtype in ODOMETRY and builder.odometry_topic is None:
                builder.track(topic, odometry=True)
            if topic in builder.rows or topic == builder.odometry_topic or topic in TF_TOPICS:
                builder.add(topic, int(bag.log_ns[k]), bag.io.raw(bag.locations[k]))

    def _pair_again(self, ended: bool, taken: int) -> _FollowDataset | None:
        """The frames paired anew when messages came since the last pairing, None otherwise. Pairing
        costs time in the frames recorded so far (about 90 us a scan): on a long recording it is
        done at most once per four times its own cost, so it never takes most of the time."""
        self._unpaired += taken
        if not ended and (not self._unpaired or self.clock() - self._paired_at < 4 * self._pair_cost):
            return None
        started = self.clock()
        dataset = self._frames_now(ended)
        self._paired_at, self._pair_cost = self.clock(), self.clock() - started
        if dataset is not None:
            self._unpaired = 0
        return dataset

    def _frames_now(self, ended: bool) -> _FollowDataset | None:
        """The frames recorded so far; None while the recording cannot give a frame yet (no scan,
        no pose, no camera_info yet) unless it has ended (then the reason is raised)."""
        if self.bag is None or self.builder is None:
            if ended:
                raise TerraError(f"{self.path}: no storage file (.mcap or .db3) appeared; nothing recorded")
            return None
        try:
            dataset = _FollowDataset(self.bag, self.builder, self.config, self.root, self.name)
        except TerraError:
            if ended:
                raise
            return None
        if dataset.needs_odometry:
            raise TerraError(
                f"{self.path}: the recording has no poses ({dataset.pose_source}); "
                "--follow needs /tf or an odometry topic"
            )
        self.dataset = dataset
        return dataset

    def _settled(self, refs: list[tuple[float, tuple, np.ndarray]]) -> int:
        """How many leading frames can no longer change: the recording is `horizon` s past them."""
        assert self.bag is not None
        latest = self.bag.end_ns * 1e-9
        stamps = np.array([r[0] for r in refs], float)
        return int(np.searchsorted(stamps, latest - self.horizon, side="right"))

    def _size_unchanged(self) -> bool:
        size = self.bag.size() if self.bag is not None else -1
        if size != self._size:
            self._size, self.last_growth = size, self.clock()
            return False
        return True


def _recording_stem(file: Path) -> str:
    """A recording's name from its storage file, as terra.datasets.ros.bag.recording_name gives it."""
    stem = file.name.removesuffix(".bag.active").removesuffix(".bag") if ".bag" in file.name else file.stem
    return stem[:-2] if stem.endswith("_0") else stem


def _check_prefix(path: Path, refs: list, fused: list) -> None:
    """The frames already handed on must be the first frames of the recording as it is now."""
    if len(refs) < len(fused):
        raise TerraError(f"{path}: the recording now pairs {len(refs)} frames, {len(fused)} were already mapped")
    for k, (old, new) in enumerate(zip(fused, refs, strict=False)):
        if old[0] != new[0] or old[1] != new[1] or not np.array_equal(old[2], new[2]):
            raise TerraError(
                f"{path}: frame {k} (t = {old[0]:.3f} s) changed after it was mapped (a late message or TF edge); "
                "map the finished recording without --follow"
            )
