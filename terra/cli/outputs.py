"""One rule for existing outputs, the same in every command that writes a file or a folder:

- an output that does not exist yet, or an empty folder, is written;
- an existing one is refused with one line naming it, unless --overwrite: then it is replaced
  atomically (the new output appears whole, or the old one stays);
- where resuming is defined, an unfinished run is resumed instead of refused: `terra map` (its
  checkpoint, OUT.partial/) and `terra demo` (its finished steps);
- something that is not the command's own kind of output (a folder of other files where a bundle
  or a report is expected) is never replaced, even with --overwrite.

No commands live here.
"""

from __future__ import annotations

from pathlib import Path

from terra.errors import TerraError


def exists(path: Path) -> bool:
    """Whether `path` is a file or a non-empty folder (an empty folder counts as absent)."""
    path = Path(path)
    if path.is_dir():
        return any(path.iterdir())
    return path.exists()


def refuse_existing(path: Path, overwrite: bool) -> None:
    """TerraError when `path` holds something and --overwrite was not given (the same words as
    every other command that refuses an existing output)."""
    if not overwrite and exists(path):
        raise TerraError(f"{path}: exists (pass --overwrite to replace it)")
