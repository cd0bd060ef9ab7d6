"""Resumable mapping: the fusion state saved every few frames in a sibling work folder.

`BUNDLE.partial/state` is itself written atomically (terra.bundle.BundleWriter), so a killed
process leaves either the previous checkpoint or the new one, never half of one. A checkpoint is
only used when its fingerprint (config, dataset, global map) matches the current run.
"""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from terra.bundle import Bundle, BundleWriter, dumps_json
from terra.errors import TerraError


def fingerprint(obj: Any) -> str:
    """SHA-256 of the canonical JSON of `obj`."""
    return hashlib.sha256(dumps_json(obj).encode()).hexdigest()


class Checkpoint:
    """The work folder of an unfinished `terra map` run writing to `out`."""

    def __init__(self, out: Path):
        out = Path(out)
        self.folder = out.with_name(out.name + ".partial")
        self.path = self.folder / "state"

    def load(self, key: str) -> tuple[int, dict[str, np.ndarray], dict] | None:
        """(next frame, arrays, metadata) of a matching checkpoint, or None."""
        if not self.exists():
            return None
        try:
            bundle = Bundle(self.path)
            meta = bundle.json("state/meta.json", verify=True)
            if meta.get("fingerprint") != key:
                return None
            arrays = {name: bundle.array(f"state/{name}", verify=True) for name in meta["arrays"]}
        except (TerraError, KeyError, TypeError):
            return None  # unreadable checkpoint: start over rather than trust it
        return int(meta["next_frame"]), arrays, meta["fusion"]

    def save(self, key: str, next_frame: int, arrays: dict[str, np.ndarray], fusion_meta: dict) -> None:
        """Replace the checkpoint atomically. When that fails (a full disk), the previous checkpoint
        stays to resume from; without one, the work folder goes too, so a failed run leaves nothing."""
        writer = None
        try:
            writer = BundleWriter(self.path, what="mapping checkpoint")
            for name, array in sorted(arrays.items()):
                writer.put_array(f"state/{name}", array)
            writer.put_json(
                "state/meta.json",
                {"fingerprint": key, "next_frame": int(next_frame), "arrays": sorted(arrays), "fusion": fusion_meta},
            )
            writer.commit()
        except BaseException:
            if writer is not None:
                writer.abort()
            if not self.exists():
                self.discard()
            raise

    def exists(self) -> bool:
        """Whether a complete checkpoint is saved (its manifest is written last)."""
        return (self.path / "manifest.json").is_file()

    def discard(self) -> None:
        shutil.rmtree(self.folder, ignore_errors=True)
