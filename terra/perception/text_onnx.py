"""The light text runtime: a sentence model's ONNX export run with onnxruntime and `tokenizers`.

Same vectors as sentence-transformers (to EXPORT_TOLERANCE, checked at export and on every load)
without importing torch: a fresh process embeds its first query in tens of milliseconds after a
~0.2 s model load. The export itself is made once per machine (terra.perception.text_export).

Determinism: every distinct text is encoded alone, with no padding, so its vector depends only on
the text itself, never on the other texts of the call or on what the process embedded before.
That makes a per-text cache exact: repeated texts (a robot asking again) cost a dictionary lookup,
and, across processes, a file read: a CLI query with a known text never starts onnxruntime.

`prepare_export` finds or makes the export (terra.perception.text_export describes the folder):
under a file lock, into a temporary sibling that is published by rename only after this runtime
gave sentence-transformers' vectors for every probe text.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import threading
from collections import OrderedDict
from collections.abc import Callable
from importlib import metadata
from pathlib import Path

import numpy as np

from terra.bundle import sibling_tmp_dir
from terra.errors import TerraError
from terra.perception.text_export import (
    EXPORT_TOLERANCE,
    LOCK_TIMEOUT_S,
    MODEL_FILE,
    PROBE_TEXTS,
    TOKENIZER_FILE,
    ExportedTextModel,
    ExportUnavailable,
    export_folder,
    export_sentence_model,
    read_export,
)

CACHED_TEXTS = 4096  # vectors kept in memory per embedder (least recently used dropped first)
STORED_TEXTS = 4096  # vectors kept on disk per export and onnxruntime version (then no more are written)


class OnnxSession:
    """onnxruntime + tokenizers over an ExportedTextModel: one text in, its unit vector out.
    Creating it (~0.2 s) checks the first `probes` probe texts against sentence-transformers'
    vectors in export.json (ExportUnavailable when they differ by more than EXPORT_TOLERANCE).
    `threads`: intra-op threads (1: a query is ~4 ms, and one thread keeps the bits independent
    of the machine's core count)."""

    def __init__(self, model: ExportedTextModel, threads: int = 1, probes: int = 1):
        try:
            import onnxruntime
            from tokenizers import Tokenizer
        except ImportError as exc:
            raise ExportUnavailable(f"the light text runtime needs onnxruntime and tokenizers ({exc})") from None
        options = onnxruntime.SessionOptions()
        options.intra_op_num_threads = threads
        options.inter_op_num_threads = 1
        options.log_severity_level = 3
        try:
            self._session = onnxruntime.InferenceSession(
                str(model.model_path), options, providers=["CPUExecutionProvider"]
            )
            self._tokenizer = Tokenizer.from_file(str(model.tokenizer_path))
        except Exception as exc:  # onnxruntime and tokenizers raise their own types for unreadable files
            raise ExportUnavailable(f"{model.folder}: cannot load the export ({type(exc).__name__}: {exc})") from None
        # sentence-transformers truncates at the model's max_seq_length and pads only batches.
        self._tokenizer.no_padding()
        self._tokenizer.enable_truncation(model.max_seq_length)
        self._check_probe(model, probes)

    def _check_probe(self, model: ExportedTextModel, probes: int) -> None:
        probe = model.info.get("probe") or {}
        texts, expected = probe.get("texts") or [], np.asarray(probe.get("vectors") or [], dtype=np.float32)
        if not texts or expected.ndim != 2 or expected.shape[0] != len(texts):
            raise ExportUnavailable(f"{model.folder}: export.json holds no probe vectors")
        got = np.vstack([self.encode(t) for t in texts[:probes]])
        error = float(np.abs(got - expected[:probes]).max())
        if not error <= EXPORT_TOLERANCE:
            raise ExportUnavailable(
                f"{model.folder}: onnxruntime vectors differ from sentence-transformers' by {error:.2e} "
                f"(> {EXPORT_TOLERANCE:g})"
            )

    def encode(self, text: str) -> np.ndarray:
        """(dim,) float32 unit vector of one text, alone (no padding)."""
        encoding = self._tokenizer.encode(text)
        feed = {
            "input_ids": np.asarray([encoding.ids], dtype=np.int64),
            "attention_mask": np.asarray([encoding.attention_mask], dtype=np.int64),
            "token_type_ids": np.asarray([encoding.type_ids], dtype=np.int64),
        }
        output = np.asarray(self._session.run(None, feed)[0])  # (1, dim): one text
        vector = np.asarray(output[0], dtype=np.float32)
        norm = float(np.linalg.norm(vector))
        return vector / norm if norm > 0 else vector


class OnnxTextEmbedder:
    """TextEmbedder over an export, thread-safe. Vectors come from memory (recent texts), then
    from disk (`stored/`: texts this export already embedded under this onnxruntime version, so
    a fresh process asking a known question never starts onnxruntime), then from the session,
    created on first need. `recover()` (optional) exports again when a cached export's probe
    check fails, and returns the new export."""

    def __init__(self, name: str, model: ExportedTextModel, recover: Callable[[], ExportedTextModel] | None = None):
        self.name = name
        self.dim = model.dim
        self.folder = model.folder
        self._model = model
        self._recover = recover
        self._session: OnnxSession | None = None
        self._session_lock = threading.Lock()
        self._cache: OrderedDict[str, np.ndarray] = OrderedDict()
        self._lock = threading.Lock()
        self._stored = model.folder / "vectors" / f"onnxruntime-{_version('onnxruntime')}"
        self._stored_count: int | None = None

    def load(self) -> None:
        """Start the onnxruntime session now (a service does this before it listens)."""
        self._ensure_session()

    def _ensure_session(self) -> OnnxSession:
        if self._session is None:
            with self._session_lock:
                if self._session is None:
                    self._session = self._open_session()
        return self._session

    def _open_session(self) -> OnnxSession:
        try:
            return OnnxSession(self._model)
        except ExportUnavailable as first:
            if self._recover is None:
                raise TerraError(f"text embedder {self.name!r}: {first}") from None
            try:
                self._model = self._recover()
                return OnnxSession(self._model)
            except ExportUnavailable as exc:
                raise TerraError(f"text embedder {self.name!r}: {exc}") from None

    def embed_text(self, texts: list[str]) -> np.ndarray:
        """(n, dim) float32 unit vectors, one per text; each distinct text is encoded alone once."""
        out = np.zeros((len(texts), self.dim), dtype=np.float32)
        for i, text in enumerate(texts):
            out[i] = self._vector(str(text))
        return out

    def _vector(self, text: str) -> np.ndarray:
        with self._lock:
            vector = self._cache.get(text)
            if vector is not None:
                self._cache.move_to_end(text)
                return vector
        vector = self._load_stored(text)
        if vector is None:
            vector = self._ensure_session().encode(text)  # outside the lock: requests encode in parallel
            self._store(text, vector)
        vector.setflags(write=False)
        with self._lock:
            self._cache[text] = vector
            if len(self._cache) > CACHED_TEXTS:
                self._cache.popitem(last=False)
        return vector

    def _stored_path(self, text: str) -> Path:
        return self._stored / (hashlib.sha256(text.encode("utf-8")).hexdigest()[:40] + ".npy")

    def _load_stored(self, text: str) -> np.ndarray | None:
        path = self._stored_path(text)
        try:
            vector = np.load(path, allow_pickle=False)
        except (OSError, ValueError):
            return None
        # The text itself is stored beside its vector: a hash collision or a damaged file is a miss.
        if vector.shape != (self.dim + 1,) or vector.dtype != np.float32 or not np.all(np.isfinite(vector)):
            return None
        try:
            if path.with_suffix(".txt").read_text(encoding="utf-8") != text:
                return None
        except OSError:
            return None
        return np.ascontiguousarray(vector[1:])

    def _store(self, text: str, vector: np.ndarray) -> None:
        """Keep the vector for later processes (best effort: a read-only cache just stores nothing)."""
        from terra.bundle import array_bytes, atomic_write_bytes

        try:
            if self._stored_count is None:
                self._stored.mkdir(parents=True, exist_ok=True)
                self._stored_count = sum(1 for _ in self._stored.glob("*.npy"))
            if self._stored_count >= STORED_TEXTS:
                return
            path = self._stored_path(text)
            atomic_write_bytes(path.with_suffix(".txt"), text.encode("utf-8"))
            # A leading 0 keeps the file's shape (dim + 1,) distinct from a bare vector's.
            atomic_write_bytes(path, array_bytes(np.concatenate([[0.0], vector]).astype(np.float32)))
            self._stored_count += 1
        except OSError:
            pass


def _version(package: str) -> str:
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return "none"


def prepare_export(
    name: str, source_dir: Path, package: str | None = None, root: Path | None = None, force: bool = False
) -> ExportedTextModel:
    """The checked export of `name`, made first when absent or corrupt (once across processes).
    force: export again even when the folder passes its checks (e.g. its probe vectors no longer
    match under this onnxruntime)."""
    folder = export_folder(name, Path(source_dir), package, root)
    if not force:
        try:
            return read_export(folder)
        except ExportUnavailable:
            pass
    from terra.progress import note

    # The export takes about 10 s once per machine; without a word the first query looks hung
    # (on a terminal and in a log alike).
    note(f"preparing the text model {name!r} (once, ~10 s)")
    try:
        from filelock import FileLock, Timeout

        folder.parent.mkdir(parents=True, exist_ok=True)
        lock = FileLock(str(folder) + ".lock", timeout=LOCK_TIMEOUT_S)
        with lock:
            try:
                if not force:
                    return read_export(folder)  # another process finished it while we waited
            except ExportUnavailable:
                pass
            _export_into(folder, name, Path(source_dir))
    except Timeout:
        raise ExportUnavailable(
            f"{folder}: another process held the export lock for over {LOCK_TIMEOUT_S:g} s"
        ) from None
    except OSError as exc:
        raise ExportUnavailable(f"{folder}: cannot write the export ({exc})") from None
    return read_export(folder)


def _export_into(folder: Path, name: str, source_dir: Path) -> None:
    """Export into a temporary sibling, then swap it in place of `folder` (caller holds the lock)."""
    tmp = sibling_tmp_dir(folder)
    try:
        info = export_sentence_model(name, source_dir, tmp)
        # onnxruntime + tokenizers must give sentence-transformers' vectors for every probe text
        # before the folder is published (on load, only the first one is checked again).
        OnnxSession(ExportedTextModel(tmp, tmp / MODEL_FILE, tmp / TOKENIZER_FILE, info), probes=len(PROBE_TEXTS))
        if folder.exists():
            stale = folder.with_name(f".{folder.name}.stale-{os.getpid()}")
            os.replace(folder, stale)
            shutil.rmtree(stale, ignore_errors=True)
        os.replace(tmp, folder)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def onnx_text_embedder(name: str, source_dir: Path, package: str | None = None) -> OnnxTextEmbedder:
    """The light runtime for the sentence model in `source_dir`, exporting it first if the cache
    has no valid export (ExportUnavailable when that cannot be done here). An export that passes
    its file checks but not its probe check under this onnxruntime is exported again once."""
    model = prepare_export(name, source_dir, package)
    return OnnxTextEmbedder(name, model, recover=lambda: prepare_export(name, source_dir, package, force=True))
