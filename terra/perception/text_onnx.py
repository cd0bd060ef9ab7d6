"""The light text runtime: a sentence model's ONNX export run with onnxruntime and `tokenizers`.

Same vectors as sentence-transformers (to EXPORT_TOLERANCE, checked at export and on every load)
without importing torch: a fresh process embeds its first query in tens of milliseconds after a
~0.2 s model load. The export itself is made once per machine (terra.perception.text_export).

Determinism: every distinct text is encoded alone, with no padding, so its vector depends only on
the text itself, never on the other texts of the call or on what the process embedded before.
That makes a per-text cache exact: repeated texts (a robot asking again) cost a dictionary lookup.

`prepare_export` finds or makes the export (terra.perception.text_export describes the folder):
under a file lock, into a temporary sibling that is published by rename only after this runtime
gave sentence-transformers' vectors for every probe text.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import threading
from collections import OrderedDict
from pathlib import Path

import numpy as np

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

CACHED_TEXTS = 4096  # vectors kept per embedder (least recently used dropped first)


class OnnxTextEmbedder:
    """TextEmbedder over an ExportedTextModel; thread-safe (one onnxruntime session, one lock
    around the cache). `threads`: onnxruntime intra-op threads (1: a query is ~4 ms anyway, and
    a single thread keeps the bits independent of the machine's core count)."""

    def __init__(self, name: str, model: ExportedTextModel, threads: int = 1, probes: int = 1):
        try:
            import onnxruntime
            from tokenizers import Tokenizer
        except ImportError as exc:
            raise ExportUnavailable(f"the light text runtime needs onnxruntime and tokenizers ({exc})") from None
        self.name = name
        self.dim = model.dim
        self.folder = model.folder
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
        self._cache: OrderedDict[str, np.ndarray] = OrderedDict()
        self._lock = threading.Lock()
        self._check_probe(model, probes)

    def _check_probe(self, model: ExportedTextModel, probes: int) -> None:
        """The first `probes` probe texts must give export.json's vectors (sentence-transformers')."""
        probe = model.info.get("probe") or {}
        texts, expected = probe.get("texts") or [], np.asarray(probe.get("vectors") or [], dtype=np.float32)
        if not texts or expected.shape != (len(texts), self.dim):
            raise ExportUnavailable(f"{model.folder}: export.json holds no probe vectors")
        texts, expected = texts[:probes], expected[:probes]
        got = np.vstack([self._encode(t) for t in texts])
        error = float(np.abs(got - expected).max())
        if not error <= EXPORT_TOLERANCE:
            raise ExportUnavailable(
                f"{model.folder}: onnxruntime vectors differ from sentence-transformers' by {error:.2e} "
                f"(> {EXPORT_TOLERANCE:g})"
            )

    def _encode(self, text: str) -> np.ndarray:
        """(dim,) float32 unit vector of one text, alone (no padding)."""
        encoding = self._tokenizer.encode(text)
        feed = {
            "input_ids": np.asarray([encoding.ids], dtype=np.int64),
            "attention_mask": np.asarray([encoding.attention_mask], dtype=np.int64),
            "token_type_ids": np.asarray([encoding.type_ids], dtype=np.int64),
        }
        vector = np.asarray(self._session.run(None, feed)[0][0], dtype=np.float32)
        norm = float(np.linalg.norm(vector))
        return vector / norm if norm > 0 else vector

    def embed_text(self, texts: list[str]) -> np.ndarray:
        """(n, dim) float32 unit vectors, one per text; each distinct text is encoded alone once
        and then served from the cache."""
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
        vector = self._encode(text)  # outside the lock: concurrent requests encode in parallel
        vector.setflags(write=False)
        with self._lock:
            self._cache[text] = vector
            if len(self._cache) > CACHED_TEXTS:
                self._cache.popitem(last=False)
        return vector


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
    tmp = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", suffix=".tmp", dir=folder.parent))
    try:
        info = export_sentence_model(name, source_dir, tmp)
        # onnxruntime + tokenizers must give sentence-transformers' vectors for every probe text
        # before the folder is published (on load, only the first one is checked again).
        OnnxTextEmbedder(
            name, ExportedTextModel(tmp, tmp / MODEL_FILE, tmp / TOKENIZER_FILE, info), probes=len(PROBE_TEXTS)
        )
        if folder.exists():
            stale = folder.with_name(f".{folder.name}.stale-{os.getpid()}")
            os.replace(folder, stale)
            shutil.rmtree(stale, ignore_errors=True)
        os.replace(tmp, folder)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def onnx_text_embedder(name: str, source_dir: Path, package: str | None = None) -> OnnxTextEmbedder:
    """The light runtime for the sentence model in `source_dir`, exporting it first if the cache
    has no valid export (ExportUnavailable when that cannot be done here). A cached export that
    loads but fails its probe check is exported again once."""
    model = prepare_export(name, source_dir, package)
    try:
        return OnnxTextEmbedder(name, model)
    except ExportUnavailable:
        return OnnxTextEmbedder(name, prepare_export(name, source_dir, package, force=True))
