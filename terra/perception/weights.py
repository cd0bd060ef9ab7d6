"""Model weight files: where they are, and what they are (name, size, SHA-256).

A map records the identity of every model that made it (the manifest's `perception.models`), and
the perception cache keys entries by it, so a changed weight file is never mistaken for the old
one. Hashes are memoised per (path, size, mtime) within the process: a 600 MB CLIP folder is
read once per run, not once per question.
"""

from __future__ import annotations

import hashlib
from dataclasses import asdict, dataclass
from pathlib import Path

from terra.errors import TerraError

# Files of a model folder that define its behaviour (weights, configs, tokenizer); READMEs, licences
# and hidden files do not change a single output, so they do not change its identity.
_FOLDER_SUFFIXES = (".json", ".safetensors", ".bin", ".txt", ".model", ".onnx", ".pt", ".pth", ".ts")
_NOT_IDENTITY = ("readme", "license", "licence")


@dataclass(frozen=True)
class ModelFile:
    """One file of a model: role (clip, terrain, masks, ...), file name (relative to the model's folder
    for folder models), size in bytes and SHA-256 hex digest."""

    role: str
    name: str
    bytes: int
    sha256: str

    def to_json(self) -> dict:
        return asdict(self)


_HASHES: dict[tuple[str, int, int], str] = {}


def file_sha256(path: Path) -> str:
    """SHA-256 hex digest of a file (memoised by path, size and modification time)."""
    path = Path(path)
    stat = path.stat()
    key = (str(path.resolve()), stat.st_size, stat.st_mtime_ns)
    if key not in _HASHES:
        digest = hashlib.sha256()
        with open(path, "rb") as f:
            for chunk in iter(lambda: f.read(1 << 22), b""):
                digest.update(chunk)
        _HASHES[key] = digest.hexdigest()
    return _HASHES[key]


def weight_file(path: Path, role: str) -> ModelFile:
    """The identity of a single weight file."""
    path = Path(path)
    return ModelFile(role, path.name, path.stat().st_size, file_sha256(path))


def folder_files(folder: Path, role: str) -> list[ModelFile]:
    """The identity of a model folder: every behaviour-defining file under it, sorted by name."""
    folder = Path(folder)
    out = []
    for path in sorted(folder.rglob("*")):
        rel = path.relative_to(folder)
        if not path.is_file() or any(part.startswith(".") for part in rel.parts):
            continue
        if path.suffix.lower() not in _FOLDER_SUFFIXES or path.name.lower().startswith(_NOT_IDENTITY):
            continue
        out.append(ModelFile(role, rel.as_posix(), path.stat().st_size, file_sha256(path)))
    return out


def combined_digest(files: list[ModelFile]) -> str:
    """One SHA-256 over the names and digests of several files (a folder model's identity)."""
    digest = hashlib.sha256()
    for f in files:
        digest.update(f"{f.name}\0{f.sha256}\n".encode())
    return digest.hexdigest()


def require_file(value: str | None, field: str, what: str, suffixes: tuple[str, ...] = ()) -> Path:
    """The configured weight file `value` of config field `field`, or a TerraError saying what to provide."""
    if not value:
        raise TerraError(f"{field} is not set: give the path of {what}")
    path = Path(value).expanduser()
    if not path.is_file():
        hint = " (it is a folder)" if path.is_dir() else ""
        raise TerraError(f"{field}: weight file {path} not found{hint}; give the path of {what}")
    if suffixes and path.suffix.lower() not in suffixes:
        raise TerraError(f"{field}: {path} is not a {' or '.join(suffixes)} file; give the path of {what}")
    return path
