"""Where an export goes: refuse an existing target unless asked to overwrite, then write it
atomically (temporary sibling, then rename), so a failed export leaves nothing half-written."""

from __future__ import annotations

from pathlib import Path

from terra.bundle import atomic_write_bytes
from terra.errors import TerraError


def check_file_target(out: Path, overwrite: bool) -> Path:
    """`out` as a Path, after checking it may be written as a file (TerraError otherwise)."""
    out = Path(out)
    if out.is_dir():
        raise TerraError(f"{out}: is a folder; give a file name for this format")
    if out.exists() and not overwrite:
        raise TerraError(f"{out}: exists (pass --overwrite to replace it)")
    if not out.parent.exists():
        raise TerraError(f"{out.parent}: parent folder does not exist")
    return out


def write_file(out: Path, data: bytes, overwrite: bool) -> Path:
    """Write `data` to file `out` atomically after `check_file_target`."""
    out = check_file_target(out, overwrite)
    atomic_write_bytes(out, data)
    return out
