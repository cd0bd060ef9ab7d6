"""The per-frame perception cache: model outputs stored on disk, so inference never runs twice.

`CachedPerception` wraps any `Perception` behind the same interface. Each image's `ImagePerception`
is stored under a key computed from everything it depends on; re-fusing with other parameters,
resuming after a crash, or building a second map from the same images (with `cache.folder` shared)
reads it back instead of running the models. `terra map --perception-only` only fills the cache.

Format (version 1; plain NumPy `.npy` files, loaded with allow_pickle=False, and JSON):

    <cache folder>/                      default: <bundle>.work/perception/ beside the bundle
      <B>/                               B = first 16 hex of the backend key
        backend.json                     {"format": 1, "key": full backend key, "identity": {...}}
        terrain_embeddings.npy           (T, D) float32 text embeddings of the terrain classes
        entries/<K[:2]>/<K>/             K = frame key, 64 hex (SHA-256)
          entry.json                     {"format", "shape": [H, W], "masks": M, "dim": D, "class_ids": bool,
                                          "files": {file name: {"bytes", "sha256"}}}
          terrain_runs.npy               (R, 2) int32 run-length terrain index image: rows of (value, length)
                                         over the (H, W) image in row-major order; value -1 = not terrain
          mask_boxes.npy                 (M, 4) int64 row0, col0, row1, col1 (end exclusive) per mask
          mask_bits.npy                  (ceil(sum of box areas / 8),) uint8: every mask's boolean crop of its
                                         box, row-major, concatenated in mask order, np.packbits (MSB first)
          mask_embeddings.npy            (M, D) float32 unit rows
          image_embedding.npy            (D,) float32 unit vector
          mask_class_ids.npy             (M,) int64, only when "class_ids" is true (labels backend)

Keys. The backend key is the SHA-256 of the canonical JSON of the backend's `identity` (backend name,
settings, terrain classes, embedder name and dimension, and for model backends each weight file's
SHA-256, never its path). The frame key is the SHA-256 of the canonical JSON of {format, backend key,
camera name, SHA-256 of the image's shape, dtype and bytes (and of the label images when the backend
reads them), and the random generator's state when the backend's output is random (noise)}.

Writes are atomic per entry: the files go into a temporary sibling folder that is renamed into place,
so a reader (or another process filling the same cache, e.g. a Dask worker) sees a whole entry or
none; when two writers race, the first rename wins and the second is discarded. An entry whose files
fail their size, checksum or shape checks is recomputed and replaced.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import shutil
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from terra.bundle import array_bytes, atomic_write_bytes, dumps_json, sibling_tmp_dir
from terra.datasets.base import CameraFrame, Frame
from terra.fileio import writing
from terra.perception.base import ImagePerception, Perception, PointPerception
from terra.perception.config import CacheConfig
from terra.perception.masks import MaskSet

CACHE_FORMAT = 1


def fingerprint(obj: object) -> str:
    """SHA-256 of the canonical JSON of `obj`."""
    return hashlib.sha256(dumps_json(obj).encode()).hexdigest()


def _array_digest(digest: hashlib._Hash, array: np.ndarray) -> None:
    array = np.ascontiguousarray(array)
    digest.update(f"{array.dtype.str}{array.shape}".encode())
    digest.update(array.tobytes())


def content_digest(camera: CameraFrame, with_labels: bool) -> str:
    """SHA-256 of an image's pixels (and its label images when `with_labels`)."""
    digest = hashlib.sha256()
    _array_digest(digest, np.asarray(camera.image))
    if with_labels:
        for labels in (camera.semantic, camera.instance):
            digest.update(b"none" if labels is None else b"labels")
            if labels is not None:
                _array_digest(digest, np.asarray(labels))
    return digest.hexdigest()


# -- encoding -------------------------------------------------------------------------------


def run_length(image: np.ndarray) -> np.ndarray:
    """(R, 2) int32 rows of (value, length) over the row-major pixels of a 2-D integer image."""
    flat = np.asarray(image).ravel()
    if flat.size == 0:
        return np.zeros((0, 2), dtype=np.int32)
    starts = np.concatenate([[0], np.flatnonzero(flat[1:] != flat[:-1]) + 1])
    lengths = np.diff(np.concatenate([starts, [flat.size]]))
    return np.stack([flat[starts], lengths], axis=1).astype(np.int32)


def run_length_decode(runs: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """The (H, W) int16 image of `run_length` rows."""
    runs = np.asarray(runs, dtype=np.int64).reshape(-1, 2)
    return np.repeat(runs[:, 0], runs[:, 1]).astype(np.int16).reshape(shape)


def pack_masks(masks: MaskSet) -> np.ndarray:
    """Every crop's bits, row-major, concatenated in mask order, packed 8 to a byte."""
    if not len(masks):
        return np.zeros(0, dtype=np.uint8)
    return np.packbits(np.concatenate([np.asarray(c, dtype=bool).ravel() for c in masks.crops]))


def unpack_masks(shape: tuple[int, int], boxes: np.ndarray, bits: np.ndarray, class_ids: np.ndarray | None) -> MaskSet:
    """The MaskSet of `pack_masks` output and its boxes."""
    boxes = np.asarray(boxes, dtype=np.int64).reshape(-1, 4)
    sizes = [(int(r1 - r0), int(c1 - c0)) for r0, c0, r1, c1 in boxes]
    total = sum(h * w for h, w in sizes)
    flat = np.unpackbits(np.asarray(bits, dtype=np.uint8), count=total).astype(bool)
    crops, at = [], 0
    for h, w in sizes:
        crops.append(flat[at : at + h * w].reshape(h, w))
        at += h * w
    return MaskSet(shape, boxes, crops, class_ids)


def encode(seen: ImagePerception) -> dict[str, np.ndarray]:
    """The arrays of a cache entry (see the module docstring)."""
    arrays = {
        "terrain_runs": run_length(seen.terrain),
        "mask_boxes": np.asarray(seen.masks.boxes, dtype=np.int64).reshape(-1, 4),
        "mask_bits": pack_masks(seen.masks),
        "mask_embeddings": np.asarray(seen.mask_embeddings, dtype=np.float32),
        "image_embedding": np.asarray(seen.image_embedding, dtype=np.float32),
    }
    if seen.masks.class_ids is not None:
        arrays["mask_class_ids"] = np.asarray(seen.masks.class_ids, dtype=np.int64)
    return arrays


class CorruptEntry(Exception):
    """A cache entry that does not pass its checks (it is recomputed)."""


def decode(arrays: dict[str, np.ndarray], meta: dict, dim: int) -> ImagePerception:
    """The ImagePerception of an entry's arrays, after checking every shape against `meta`."""
    shape = tuple(int(v) for v in meta["shape"])
    m = int(meta["masks"])
    runs, boxes = arrays["terrain_runs"], arrays["mask_boxes"]
    if len(shape) != 2 or runs.ndim != 2 or runs.shape[1:] != (2,) or int(runs[:, 1].sum()) != shape[0] * shape[1]:
        raise CorruptEntry("terrain runs do not cover the image")
    if boxes.shape != (m, 4) or (
        m and (boxes.min() < 0 or boxes[:, 2].max() > shape[0] or boxes[:, 3].max() > shape[1])
    ):
        raise CorruptEntry("mask boxes do not fit the image")
    if np.any(boxes[:, 2] < boxes[:, 0]) or np.any(boxes[:, 3] < boxes[:, 1]):
        raise CorruptEntry("mask boxes are inverted")
    area = int(((boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])).sum())
    if arrays["mask_bits"].shape != ((area + 7) // 8,):
        raise CorruptEntry("mask bits do not match the boxes")
    if arrays["mask_embeddings"].shape != (m, dim) or arrays["image_embedding"].shape != (dim,):
        raise CorruptEntry(f"embeddings are not {dim}-d")
    class_ids = arrays.get("mask_class_ids")
    if bool(meta.get("class_ids")) != (class_ids is not None) or (class_ids is not None and class_ids.shape != (m,)):
        raise CorruptEntry("mask class ids do not match the masks")
    masks = unpack_masks(shape, boxes, arrays["mask_bits"], class_ids)
    return ImagePerception(run_length_decode(runs, shape), masks, arrays["mask_embeddings"], arrays["image_embedding"])


# -- the folder -----------------------------------------------------------------------------


def backend_key(identity: dict) -> str:
    """The backend key of a backend `identity` (see the module docstring); its first 16 hex name its folder."""
    return fingerprint({"format": CACHE_FORMAT, "identity": identity})


class PerceptionCache:
    """The cache folder of one backend (identity) inside a cache root."""

    def __init__(self, root: Path, identity: dict):
        self.root = Path(root)
        self.backend_key = backend_key(identity)
        self.folder = self.root / self.backend_key[:16]
        description = self.folder / "backend.json"
        if not description.is_file():
            record = {"format": CACHE_FORMAT, "key": self.backend_key, "identity": identity}
            atomic_write_bytes(description, dumps_json(record).encode())

    def key(self, camera: CameraFrame, rng_state: Mapping[str, Any] | None, with_labels: bool) -> str:
        """The frame key of one image (see the module docstring)."""
        return fingerprint(
            {
                "format": CACHE_FORMAT,
                "backend": self.backend_key,
                "camera": camera.calibration.name,
                "content": content_digest(camera, with_labels),
                "rng": rng_state,
            }
        )

    def entry(self, key: str) -> Path:
        return self.folder / "entries" / key[:2] / key

    def load(self, key: str, dim: int) -> ImagePerception | None:
        """The stored perception of `key`; None when absent or corrupt (a corrupt entry is removed)."""
        folder = self.entry(key)
        if not (folder / "entry.json").is_file():
            return None
        try:
            meta = json.loads((folder / "entry.json").read_text())
            arrays = {name[:-4]: _checked_array(folder / name, info) for name, info in meta["files"].items()}
            return decode(arrays, meta, dim)
        except (CorruptEntry, OSError, ValueError, KeyError, TypeError):
            shutil.rmtree(folder, ignore_errors=True)
            return None

    def store(self, key: str, seen: ImagePerception) -> None:
        """Write the entry of `key` atomically (a concurrent writer's complete entry is kept)."""
        final = self.entry(key)
        if (final / "entry.json").is_file():
            return
        with writing(final, "perception cache entry"):
            self._store(key, seen, final)

    def _store(self, key: str, seen: ImagePerception, final: Path) -> None:
        final.parent.mkdir(parents=True, exist_ok=True)
        tmp = sibling_tmp_dir(final)
        try:
            files = {}
            for name, array in encode(seen).items():
                data = array_bytes(array)
                (tmp / f"{name}.npy").write_bytes(data)
                files[f"{name}.npy"] = {"bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()}
            meta = {
                "format": CACHE_FORMAT,
                "shape": list(seen.terrain.shape),
                "masks": len(seen.masks),
                "dim": int(np.asarray(seen.image_embedding).shape[0]),
                "class_ids": seen.masks.class_ids is not None,
                "files": files,
            }
            atomic_write_bytes(tmp / "entry.json", dumps_json(meta).encode())
            if final.exists() and not (final / "entry.json").is_file():
                shutil.rmtree(final, ignore_errors=True)  # a leftover without its entry.json
            os.rename(tmp, final)
        except OSError:
            if not (final / "entry.json").is_file():
                raise
        finally:
            shutil.rmtree(tmp, ignore_errors=True)

    def terrain_embeddings(self, compute: Callable[[], np.ndarray], dim: int) -> np.ndarray:
        """The backend's terrain class embeddings, computed once and kept beside the entries."""
        path = self.folder / "terrain_embeddings.npy"
        if path.is_file():
            try:
                stored = np.load(path, allow_pickle=False)
                if stored.ndim == 2 and stored.shape[1] == dim and stored.dtype == np.float32:
                    return stored
            except (OSError, ValueError):
                pass
        vectors = np.asarray(compute(), dtype=np.float32)
        atomic_write_bytes(path, array_bytes(vectors))
        return vectors


def _checked_array(path: Path, info: dict) -> np.ndarray:
    data = path.read_bytes()
    if len(data) != int(info["bytes"]) or hashlib.sha256(data).hexdigest() != info["sha256"]:
        raise CorruptEntry(f"{path.name} fails its checksum")
    return np.load(io.BytesIO(data), allow_pickle=False)


# -- the wrapper ----------------------------------------------------------------------------


@dataclass
class CacheCounts:
    """What a CachedPerception did: images read back from the cache and images computed."""

    hits: int = 0
    computed: int = 0

    def to_json(self) -> dict[str, int]:
        return {"hits": self.hits, "computed": self.computed}


class CachedPerception(Perception):
    """Any Perception behind the same interface, its per-image outputs read from / written to a cache."""

    def __init__(self, inner: Perception, cache: PerceptionCache):
        super().__init__(
            inner.terrain,
            inner.proposer,
            inner.mask_embedder,
            inner.image_embedder,
            inner.point_labeler,
            backend=inner.backend,
            identity=inner.identity,
            models=inner.models,
            random=inner.random,
            uses_labels=inner.uses_labels,
        )
        self.inner = inner
        self.cache = cache
        self.counts = CacheCounts()

    @property
    def embedder(self) -> str:
        return self.inner.embedder

    @property
    def dim(self) -> int:
        return self.inner.dim

    @property
    def terrain_classes(self) -> list[str]:
        return self.inner.terrain_classes

    def perceive(self, camera: CameraFrame, rng: np.random.Generator) -> ImagePerception:
        state = rng.bit_generator.state if self.random else None  # read before the backend draws from it
        key = self.cache.key(camera, state, self.uses_labels)
        found = self.cache.load(key, self.dim)
        if found is not None:
            self.counts.hits += 1
            return found
        seen = self.inner.perceive(camera, rng)
        self.cache.store(key, seen)
        self.counts.computed += 1
        return seen

    def terrain_embeddings(self) -> np.ndarray:
        return self.cache.terrain_embeddings(self.inner.terrain_embeddings, self.dim)

    def perceive_points(self, frame: Frame, rng: np.random.Generator) -> PointPerception | None:
        return self.inner.perceive_points(frame, rng)  # per-point labels are a lookup: nothing to cache


def cache_enabled(perception: Perception, config: CacheConfig) -> bool:
    """Whether `config` caches this perception (auto: when it runs models)."""
    return config.mode == "on" or (config.mode == "auto" and bool(perception.models))


def default_cache_folder(out: Path) -> Path:
    """The cache folder of the bundle `out`: OUT.work/perception beside it."""
    out = Path(out)
    return out.with_name(out.name + ".work") / "perception"


def cache_root(config: CacheConfig, out: Path) -> Path:
    """The cache root `config` names for the bundle `out` (its folder, or OUT.work/perception)."""
    return Path(config.folder).expanduser() if config.folder else default_cache_folder(out)


def cache_identity(perception: Perception) -> dict:
    """What keys `perception`'s outputs: its identity, or its backend name and embedder when it has none."""
    return perception.identity or {"backend": perception.backend, "embedder": [perception.embedder, perception.dim]}


def cached(perception: Perception, config: CacheConfig, out: Path) -> Perception:
    """`perception` behind the cache `config` asks for (the perception itself when the cache is off)."""
    if not cache_enabled(perception, config):
        return perception
    return CachedPerception(perception, PerceptionCache(cache_root(config, out), cache_identity(perception)))
