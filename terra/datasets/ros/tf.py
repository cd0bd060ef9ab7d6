"""A TF tree from /tf_static and /tf (or an odometry topic), with poses looked up at any time.

Each edge holds T_parent_child, the pose of the child frame in its parent frame (p_parent =
T_parent_child p_child), as geometry_msgs/TransformStamped states it (header.frame_id = parent,
child_frame_id = child). Static edges hold one pose; dynamic edges a time series (seconds) that
is interpolated: translation linearly, rotation by slerp. A lookup between two frames walks both
up to their common ancestor and composes the edges at each requested time.
"""

from __future__ import annotations

from array import array
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from terra.errors import TerraError
from terra.geometry import pose_from_xyz_quat


@dataclass
class _Track:
    """A dynamic edge: stamps (K,) seconds, increasing; xyz (K, 3) metres; quat (K, 4) [x, y, z, w]."""

    parent: str
    # Filled as flat arrays of doubles while a bag is read (8 bytes a number, not a Python object).
    stamps: array | np.ndarray = field(default_factory=lambda: array("d"))
    xyz: array | np.ndarray = field(default_factory=lambda: array("d"))
    quat: array | np.ndarray = field(default_factory=lambda: array("d"))

    def freeze(self) -> None:
        stamps = np.asarray(self.stamps, float)
        order = np.argsort(stamps, kind="stable")
        stamps = stamps[order]
        keep = np.ones(len(stamps), bool)
        keep[:-1] = np.diff(stamps) > 0  # duplicates: keep the last sample of a stamp
        self.stamps = stamps[keep]
        self.xyz = np.asarray(self.xyz, float).reshape(-1, 3)[order][keep]
        quat = np.asarray(self.quat, float).reshape(-1, 4)[order][keep]
        self.quat = quat / np.linalg.norm(quat, axis=1, keepdims=True)

    def append(self, stamp: float, xyz_quat: np.ndarray) -> None:
        """One sample, while the bag is read (before `freeze`)."""
        if not (isinstance(self.stamps, array) and isinstance(self.xyz, array) and isinstance(self.quat, array)):
            raise TerraError(f"TF edge to '{self.parent}': a transform was added after the tree was frozen")
        self.stamps.append(float(stamp))
        self.xyz.extend(float(v) for v in xyz_quat[:3])
        self.quat.extend(float(v) for v in xyz_quat[3:])

    def at(self, times: np.ndarray, max_gap: float) -> tuple[np.ndarray, np.ndarray]:
        """T_parent_child (M, 4, 4) at `times` and whether each is covered: inside the series and
        between samples at most `max_gap` seconds apart (or exactly on a sample)."""
        stamps, xyz = np.asarray(self.stamps), np.asarray(self.xyz)  # (K,) and (K, 3) once frozen
        out = np.tile(np.eye(4), (len(times), 1, 1))
        if len(stamps) == 0:
            return out, np.zeros(len(times), bool)
        i = np.clip(np.searchsorted(stamps, times), 0, len(stamps) - 1)
        exact = stamps[i] == times
        lo = np.clip(i - 1, 0, len(stamps) - 1)
        inside = (times >= stamps[0]) & (times <= stamps[-1])
        valid = exact | (inside & (stamps[i] - stamps[lo] <= max_gap))
        if len(stamps) > 1:
            t = np.clip(times, stamps[0], stamps[-1])
            out[:, :3, :3] = Slerp(stamps, Rotation.from_quat(self.quat))(t).as_matrix()
            for axis in range(3):
                out[:, axis, 3] = np.interp(t, stamps, xyz[:, axis])
        for k in np.flatnonzero(exact):  # on a sample: that sample, bit for bit
            out[k] = pose_from_xyz_quat(np.concatenate([xyz[i[k]], self.quat[i[k]]]))
        return out, valid


class TfTree:
    """Frames joined by static and dynamic transforms (one parent per frame, as in tf2)."""

    def __init__(self) -> None:
        self.static: dict[str, tuple[str, np.ndarray]] = {}
        self.dynamic: dict[str, _Track] = {}
        self.conflicts: list[str] = []

    def add(self, parent: str, child: str, xyz_quat: np.ndarray, stamp: float | None) -> None:
        """One transform: static when `stamp` is None. A frame already attached to another
        parent keeps its first parent (the conflict is recorded)."""
        parent, child = parent.lstrip("/"), child.lstrip("/")
        known = self.static.get(child, (None,))[0] or (self.dynamic[child].parent if child in self.dynamic else None)
        if known is not None and known != parent:
            self.conflicts.append(f"'{child}' has parents '{known}' and '{parent}'")
            return
        if stamp is None:
            self.static[child] = (parent, pose_from_xyz_quat(xyz_quat))
            return
        self.dynamic.setdefault(child, _Track(parent)).append(stamp, xyz_quat)

    def copy(self) -> TfTree:
        """A copy that can be frozen while this tree keeps taking transforms (a recording that grows)."""
        other = TfTree()
        other.static = dict(self.static)
        other.conflicts = list(self.conflicts)
        for child, track in self.dynamic.items():
            other.dynamic[child] = _Track(
                track.parent, array("d", track.stamps), array("d", track.xyz), array("d", track.quat)
            )
        return other

    def freeze(self) -> None:
        """Sort the time series (call once every transform is added)."""
        for track in self.dynamic.values():
            track.freeze()

    def parent(self, frame: str) -> str | None:
        if frame in self.static:
            return self.static[frame][0]
        return self.dynamic[frame].parent if frame in self.dynamic else None

    def frames(self) -> list[str]:
        names = set(self.static) | set(self.dynamic)
        names |= {p for p, _ in self.static.values()} | {t.parent for t in self.dynamic.values()}
        return sorted(names)

    def edges(self) -> list[dict]:
        """Every edge as plain data: parent, child, static, samples, first/last stamp."""
        rows = [{"parent": p, "child": c, "static": True, "samples": 1} for c, (p, _) in self.static.items()]
        for child, t in self.dynamic.items():
            rows.append(
                {
                    "parent": t.parent,
                    "child": child,
                    "static": False,
                    "samples": int(len(t.stamps)),
                    "first": float(t.stamps[0]) if len(t.stamps) else None,
                    "last": float(t.stamps[-1]) if len(t.stamps) else None,
                }
            )
        return sorted(rows, key=lambda r: (r["parent"], r["child"]))

    def ancestors(self, frame: str) -> list[str]:
        """`frame`, its parent, its parent's parent, ... up to the root of its tree."""
        chain = [frame]
        while (p := self.parent(chain[-1])) is not None and p not in chain:
            chain.append(p)
        return chain

    def path(self, target: str, source: str) -> tuple[list[str], list[str]]:
        """Frames from `source` up to the common ancestor and from `target` up to it; TerraError
        naming both frames and listing the known ones when the tree does not connect them."""
        for name in (target, source):
            if name not in self.frames():
                raise TerraError(
                    f"TF does not connect '{target}' and '{source}': no transform has frame '{name}'; "
                    f"frames: {quoted(self.frames())}"
                )
        up_t, up_s = self.ancestors(target), self.ancestors(source)
        common = next((f for f in up_s if f in up_t), None)
        if common is None:
            raise TerraError(
                f"TF does not connect '{target}' and '{source}' (their trees have roots '{up_t[-1]}' and "
                f"'{up_s[-1]}'); frames: {quoted(self.frames())}"
            )
        return up_s[: up_s.index(common) + 1], up_t[: up_t.index(common) + 1]

    def is_static(self, target: str, source: str) -> bool:
        """Whether the chain between the two frames holds static transforms only."""
        from_source, from_target = self.path(target, source)
        return not any(f in self.dynamic for f in from_source[:-1] + from_target[:-1])

    def lookup(
        self, target: str, source: str, times: np.ndarray, max_gap: float = 0.5
    ) -> tuple[np.ndarray, np.ndarray]:
        """T_target_source (M, 4, 4) at `times` (seconds) and (M,) whether every dynamic edge of
        the chain covers each time (see _Track.at)."""
        times = np.atleast_1d(np.asarray(times, float))
        from_source, from_target = self.path(target, source)
        root_source, ok_s = self._to_root(from_source, times, max_gap)
        root_target, ok_t = self._to_root(from_target, times, max_gap)
        return _rigid_inverse(root_target) @ root_source, ok_s & ok_t

    def _to_root(self, chain: list[str], times: np.ndarray, max_gap: float) -> tuple[np.ndarray, np.ndarray]:
        """T_ancestor_frame for chain = [frame, parent, ..., ancestor]."""
        T = np.tile(np.eye(4), (len(times), 1, 1))
        valid = np.ones(len(times), bool)
        for child in chain[:-1]:
            if child in self.static:
                edge = self.static[child][1][None]
            else:
                edge, ok = self.dynamic[child].at(times, max_gap)
                valid &= ok
            T = edge @ T
        return T, valid


def quoted(frames: list[str]) -> str:
    """Frame names for a message, each quoted so an empty name (a header without frame_id) shows."""
    return ", ".join(f"'{name}'" for name in frames) or "none"


def _rigid_inverse(T: np.ndarray) -> np.ndarray:
    """Inverse of rigid poses (M, 4, 4): [R^T, -R^T t]."""
    out = np.tile(np.eye(4), (len(T), 1, 1))
    Rt = np.transpose(T[:, :3, :3], (0, 2, 1))
    out[:, :3, :3] = Rt
    out[:, :3, 3] = -np.einsum("mij,mj->mi", Rt, T[:, :3, 3])
    return out
