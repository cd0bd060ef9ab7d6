"""Write a dataset folder atomically: everything goes into a hidden sibling folder that is renamed
into place at the end, so a crash or a bad argument never leaves a half-written dataset."""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Callable

from terra.datasets.base import Dataset
from terra.datasets.folder_io import write_classes
from terra.datasets.ground_truth import write_ground_truth
from terra.errors import TerraError

FORMATS = ("terra-folder", "semantickitti", "kitti-raw", "rosbag1", "rosbag2")


def check_output(out: Path, overwrite: bool) -> None:
    """TerraError unless `out` can be written: absent, empty, or `overwrite`."""
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise TerraError(f"{out}: exists and is not a folder")
    if out.is_dir() and any(out.iterdir()) and not overwrite:
        raise TerraError(f"{out}: folder exists and is not empty (pass --overwrite to replace it)")
    if not out.parent.exists():
        raise TerraError(f"{out.parent}: parent folder does not exist")


def atomic_folder(out: Path, overwrite: bool, fill: Callable[[Path], None]) -> Path:
    """Call fill(tmp) on a fresh sibling folder, then move it to `out` (replacing it if allowed)."""
    out = Path(out).resolve()
    check_output(out, overwrite)
    tmp = out.parent / f".{out.name}.tmp-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    try:
        fill(tmp)
        if out.exists():
            old = out.parent / f".{out.name}.old-{os.getpid()}"
            out.rename(old)
            tmp.rename(out)
            shutil.rmtree(old, ignore_errors=True)
        else:
            tmp.rename(out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out


def write_dataset(dataset: Dataset, out: str | Path, format: str = "terra-folder", overwrite: bool = False,
                  progress: bool = True, extra: Callable[[Path], None] | None = None, bag_images: str = "jpeg") -> Path:
    """Write all frames of `dataset`, its class table (classes.json) and, when it has one, its
    ground truth (ground_truth/) to folder `out` in `format`. `extra(tmp_root)` may add files
    before the folder is moved into place. `bag_images`: jpeg (CompressedImage) or raw (Image
    rgb8) for the bag formats. Returns the folder."""
    if format not in FORMATS:
        raise TerraError(f"unknown format {format!r}; expected one of: {', '.join(FORMATS)}")
    if bag_images not in ("jpeg", "raw"):
        raise TerraError(f"unknown bag image format {bag_images!r}; expected jpeg or raw")

    def fill(root: Path) -> None:
        shift = None  # from the dataset's map frame to the written one, when a format moves it
        if format == "terra-folder":
            from terra.datasets.terra_folder import write_terra_folder

            write_terra_folder(dataset, root, show_progress=progress)
        elif format == "kitti-raw":
            from terra.datasets.kitti_raw_writer import write_kitti_raw

            shift = write_kitti_raw(dataset, root, show_progress=progress)
        elif format in ("rosbag1", "rosbag2"):
            from terra.sim.bag_writer import write_bag

            write_bag(dataset, root, version=int(format[-1]), image_format=bag_images, show_progress=progress)
        else:
            from terra.datasets.semantickitti import write_semantickitti

            write_semantickitti(dataset, root, show_progress=progress)
        write_classes(root, dataset.classes)
        if hasattr(dataset, "ground_truth"):
            gt = dataset.ground_truth()
            write_ground_truth(root, gt if shift is None else gt.translated(shift))
        if extra is not None:
            extra(root)

    return atomic_folder(Path(out), overwrite, fill)
