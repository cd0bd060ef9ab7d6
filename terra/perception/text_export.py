"""A sentence-transformers model exported once to ONNX and kept in the user's cache folder.

Query commands must answer in about a second, and importing sentence-transformers and torch alone
takes several. So the text model runs through onnxruntime and the `tokenizers` package instead
(terra.perception.text_onnx); this module makes that export, once per model and machine:

- Where: `<cache>/text/<name>-<key>/` with `model.onnx`, `tokenizer.json` and `export.json`.
  `<cache>` is $TERRA_CACHE_DIR, else the platform's user cache folder (~/.cache/terra on
  Linux). `key` hashes the source model's files (names and sizes), the package version and
  EXPORT_FORMAT, so a new model or a new export recipe gets a new folder.
- How: the model is loaded with sentence-transformers and traced with torch.onnx, token
  embeddings -> mean pooling over the attention mask -> L2 normalisation, exactly as its modules
  do. Before the folder is published, onnxruntime's vectors for PROBE_TEXTS must equal
  sentence-transformers' to EXPORT_TOLERANCE; the probe vectors are recorded in export.json.
- Concurrency (terra.perception.text_onnx.prepare_export): the export is assembled in a
  temporary sibling folder and renamed into place, so a reader never sees half an export; a
  file lock beside the folder makes concurrent first uses (several CLI processes, a service and
  a CLI) export once while the others wait for it.
- Integrity: every load checks each file against export.json: one whose size, modification time
  and inode are those recorded at export is the file written then; any other is hashed and must
  match its SHA-256 (about 50 ms for the 90 MB model). A folder that fails is exported again.
  The runtime also re-checks the first probe vector on load (terra.perception.text_onnx).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from sentence_transformers import SentenceTransformer

EXPORT_FORMAT = 1
EXPORT_TOLERANCE = 1e-5  # max |ONNX - sentence-transformers| per vector component
EXPORT_JSON = "export.json"
MODEL_FILE = "model.onnx"
TOKENIZER_FILE = "tokenizer.json"
PROBE_TEXTS = (
    "find the dumpster",
    "  Get bike from the BICYCLE rack!  ",
    "grass",
    "a large parking lot surrounded by buildings "
    "next to the tall office block, with trees along its northern edge and two rows of parked cars",
)
LOCK_TIMEOUT_S = 900.0  # how long a process waits for another one's export


class ExportUnavailable(Exception):
    """The ONNX export cannot be made or used here (a library or the source model is missing, the
    cache folder is not writable, or the export disagrees with sentence-transformers)."""


@dataclass(frozen=True)
class ExportedTextModel:
    """A checked export: the ONNX model file, its tokenizer file and export.json's content."""

    folder: Path
    model_path: Path
    tokenizer_path: Path
    info: dict[str, Any]

    @property
    def dim(self) -> int:
        return int(self.info["dim"])

    @property
    def max_seq_length(self) -> int:
        return int(self.info["max_seq_length"])


def cache_root() -> Path:
    """Terra's user cache folder: $TERRA_CACHE_DIR, else the platform's (~/.cache/terra on Linux)."""
    explicit = os.environ.get("TERRA_CACHE_DIR")
    if explicit:
        return Path(explicit).expanduser()
    import platformdirs

    return Path(platformdirs.user_cache_dir("terra", appauthor=False))


def source_key(name: str, source_dir: Path, package: str | None = None) -> str:
    """16 hex digits naming one export: the embedder name, the source files (relative names and
    sizes), the package version and EXPORT_FORMAT. Cheap: no file is read."""
    files = sorted(p for p in source_dir.rglob("*") if p.is_file() and "__pycache__" not in p.parts)
    listing = [[p.relative_to(source_dir).as_posix(), p.stat().st_size] for p in files]
    version = metadata.version(package) if package else ""
    text = json.dumps({"name": name, "files": listing, "package": [package, version], "format": EXPORT_FORMAT})
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def export_folder(name: str, source_dir: Path, package: str | None = None, root: Path | None = None) -> Path:
    """Where the export of `name` from `source_dir` lives (whether or not it exists yet)."""
    return (root or cache_root()) / "text" / f"{name}-{source_key(name, source_dir, package)}"


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _file_entry(path: Path, data: bytes) -> dict[str, Any]:
    stat = path.stat()
    return {"bytes": len(data), "sha256": _sha256(data), "mtime_ns": stat.st_mtime_ns, "inode": stat.st_ino}


def _unchanged(path: Path, entry: dict[str, Any]) -> bool:
    """Whether `path` is the very file export.json describes: same size, modification time and
    inode as when it was written (the folder appears by an atomic rename, which keeps them)."""
    try:
        stat = path.stat()
    except OSError:
        return False
    return (stat.st_size, stat.st_mtime_ns, stat.st_ino) == (
        entry.get("bytes"),
        entry.get("mtime_ns"),
        entry.get("inode"),
    )


def read_export(folder: Path) -> ExportedTextModel:
    """The export in `folder`, every file checked against export.json; ExportUnavailable when the
    folder is missing, incomplete or corrupt (the caller exports again). A file whose size,
    modification time and inode are those recorded is trusted without re-hashing; any other
    (copied, touched, truncated, rewritten) is hashed and must match its SHA-256."""
    try:
        info = json.loads((folder / EXPORT_JSON).read_text())
        if info.get("format") != EXPORT_FORMAT:
            raise ExportUnavailable(f"{folder / EXPORT_JSON}: format {info.get('format')!r}, expected {EXPORT_FORMAT}")
        files = info.get("files", {})
        for file_name in (MODEL_FILE, TOKENIZER_FILE):
            entry = files.get(file_name, {})
            if _unchanged(folder / file_name, entry):
                continue
            data = (folder / file_name).read_bytes()
            if entry.get("bytes") != len(data) or entry.get("sha256") != _sha256(data):
                raise ExportUnavailable(
                    f"{folder / file_name}: size or checksum differs from {EXPORT_JSON} (corrupt export)"
                )
    except (OSError, ValueError, AttributeError) as exc:
        raise ExportUnavailable(f"{folder}: no complete export ({exc})") from None
    return ExportedTextModel(folder, folder / MODEL_FILE, folder / TOKENIZER_FILE, info)


def export_sentence_model(name: str, source_dir: Path, out: Path) -> dict[str, Any]:
    """Export the sentence-transformers model in `source_dir` to `out` (model.onnx,
    tokenizer.json, export.json with sentence-transformers' vectors of PROBE_TEXTS, which the
    runtime checks before the folder is published). Returns export.json's content. Needs torch
    and sentence-transformers (imported here only)."""
    try:
        import torch
        from sentence_transformers import SentenceTransformer
    except ImportError as exc:
        raise ExportUnavailable(f"exporting {name!r} needs torch and sentence-transformers ({exc})") from None
    if not (source_dir / TOKENIZER_FILE).is_file():
        raise ExportUnavailable(f"{source_dir}: no {TOKENIZER_FILE}; the light runtime needs a fast tokenizer file")
    from tokenizers import Tokenizer
    from transformers.utils import logging as hf_logging

    hf_logging.disable_progress_bar()  # no "Loading weights" bar in a query command's output
    model = SentenceTransformer(str(source_dir), device="cpu").eval()
    wrapper, normalize = _pooled_encoder(model, torch)
    example = Tokenizer.from_file(str(source_dir / TOKENIZER_FILE)).encode(PROBE_TEXTS[0])
    inputs = tuple(
        torch.tensor([ids], dtype=torch.int64) for ids in (example.ids, example.attention_mask, example.type_ids)
    )
    dynamic = {k: {0: "batch", 1: "tokens"} for k in ("input_ids", "attention_mask", "token_type_ids")}
    dynamic["sentence_embedding"] = {0: "batch"}
    import warnings

    with torch.no_grad(), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the TorchScript exporter's deprecation notes
        torch.onnx.export(
            wrapper,
            inputs,
            str(out / MODEL_FILE),
            input_names=["input_ids", "attention_mask", "token_type_ids"],
            output_names=["sentence_embedding"],
            dynamic_axes=dynamic,
            opset_version=17,
            dynamo=False,
            do_constant_folding=True,
        )
    shutil.copyfile(source_dir / TOKENIZER_FILE, out / TOKENIZER_FILE)
    info = _export_info(name, model, normalize, out)
    (out / EXPORT_JSON).write_text(json.dumps(info, indent=1, sort_keys=True) + "\n")
    return info


def _export_info(name: str, model: SentenceTransformer, normalize: bool, out: Path) -> dict[str, Any]:
    """export.json's content for the files in `out`: sentence-transformers' own vectors of
    PROBE_TEXTS (which the runtime compares with its own) and each file's size and checksum."""
    reference = np.vstack(
        [model.encode([t], batch_size=1, normalize_embeddings=normalize, convert_to_numpy=True) for t in PROBE_TEXTS]
    ).astype(np.float32)
    max_seq_length = model.max_seq_length
    if max_seq_length is None:
        raise ExportUnavailable(f"exporting {name!r}: the model sets no max_seq_length")
    info: dict[str, Any] = {
        "format": EXPORT_FORMAT,
        "name": name,
        "dim": int(reference.shape[1]),
        "max_seq_length": int(max_seq_length),
        "normalize": bool(normalize),
        "probe": {"texts": list(PROBE_TEXTS), "vectors": reference.tolist()},
        "exported_with": {p: _version(p) for p in ("torch", "sentence-transformers", "onnxruntime", "tokenizers")},
        "files": {},
    }
    for file_name in (MODEL_FILE, TOKENIZER_FILE):
        info["files"][file_name] = _file_entry(out / file_name, (out / file_name).read_bytes())
    return info


def _pooled_encoder(model: Any, torch: Any) -> tuple[Any, bool]:
    """A torch module: token ids -> the model's sentence embedding (mean pooling, optional L2
    normalisation), and whether it normalises. ExportUnavailable for other module stacks."""
    modules = list(model)
    kinds = [type(m).__name__ for m in modules]
    if (
        len(modules) < 2
        or kinds[1] != "Pooling"
        or kinds[0] != "Transformer"
        or any(k != "Normalize" for k in kinds[2:])
    ):
        raise ExportUnavailable(
            f"only Transformer -> Pooling [-> Normalize] models can be exported, got {' -> '.join(kinds)}"
        )
    pooling = modules[1]
    mode = getattr(pooling, "pooling_mode", None) or (
        "mean" if getattr(pooling, "pooling_mode_mean_tokens", False) else None
    )
    if mode not in ("mean", ["mean"], ("mean",)):
        raise ExportUnavailable(f"only mean pooling can be exported, got {mode!r}")
    normalize = "Normalize" in kinds[2:]
    encoder = modules[0].auto_model.eval()

    class PooledEncoder(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.encoder = encoder

        def forward(self, input_ids, attention_mask, token_type_ids):  # noqa: ANN001 (traced)
            tokens = self.encoder(input_ids=input_ids, attention_mask=attention_mask, token_type_ids=token_type_ids)[0]
            mask = attention_mask.unsqueeze(-1).to(tokens.dtype)
            mean = (tokens * mask).sum(1) / mask.sum(1).clamp(min=1e-9)
            return torch.nn.functional.normalize(mean, p=2, dim=1) if normalize else mean

    return PooledEncoder().eval(), normalize


def _version(package: str) -> str:
    try:
        return metadata.version(package)
    except metadata.PackageNotFoundError:
        return ""
