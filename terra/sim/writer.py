"""Write a dataset folder atomically: everything goes into a hidden sibling folder that replaces the
output at the end (terra.bundle.atomic_folder, the mechanism bundles use), so a crash, a full disk
or a bad argument never leaves a half-written dataset and an existing one stays until the new one
is complete."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from terra.bundle import atomic_folder, check_output_folder
from terra.datasets.base import Dataset
from terra.datasets.folder_io import is_terra_dataset, write_classes
from terra.datasets.ground_truth import write_ground_truth
from terra.errors import TerraError

FORMATS = ("terra-folder", "semantickitti", "kitti-raw", "rosbag1", "rosbag2")


def check_output(out: str | Path, overwrite: bool) -> None:
    """TerraError unless `out` may be written: absent, empty, or (with `overwrite`) a dataset Terra
    wrote, recognised by its class table (classes.json, which every format here writes)."""
    check_output_folder(out, overwrite, "dataset Terra wrote", is_terra_dataset, "classes.json")


def check_format(format: str) -> str:
    """`format` when it names a dataset format the writer knows, else TerraError."""
    if format not in FORMATS:
        raise TerraError(f"unknown format {format!r}; expected one of: {', '.join(FORMATS)}")
    return format


def write_dataset(
    dataset: Dataset,
    out: str | Path,
    format: str = "terra-folder",
    overwrite: bool = False,
    progress: bool = True,
    extra: Callable[[Path], None] | None = None,
    bag_images: str = "jpeg",
) -> Path:
    """Write all frames of `dataset`, its class table (classes.json) and, when it has one, its
    ground truth (ground_truth/) to folder `out` in `format`. `extra(tmp_root)` may add files
    before the folder is moved into place. `bag_images`: jpeg (CompressedImage) or raw (Image
    rgb8) for the bag formats. Returns the folder."""
    check_format(format)
    if bag_images not in ("jpeg", "raw"):
        raise TerraError(f"unknown bag image format {bag_images!r}; expected jpeg or raw")

    def fill(root: Path) -> None:
        shift = None  # from the dataset's map frame to the written one, when a format moves it
        if format == "terra-folder":
            from terra.datasets.terra_folder import write_terra_folder

            write_terra_folder(dataset, root, show_progress=progress)
        elif format == "kitti-raw":
            from terra.datasets.kitti_raw_writer import write_kitti_raw

            # The world's origin on the Earth: two drives of one world (a revisit) share it.
            shift = write_kitti_raw(dataset, root, show_progress=progress, origin_is_map=True)
        elif format in ("rosbag1", "rosbag2"):
            from terra.sim.bag_writer import write_bag

            write_bag(dataset, root, version=int(format[-1]), image_format=bag_images, show_progress=progress)
        else:
            from terra.datasets.semantickitti import write_semantickitti

            write_semantickitti(dataset, root, show_progress=progress)
        write_classes(root, dataset.classes)
        ground_truth = getattr(dataset, "ground_truth", None)  # not part of the Dataset protocol
        if ground_truth is not None:
            gt = ground_truth()
            write_ground_truth(root, gt if shift is None else gt.translated(shift))
        if extra is not None:
            extra(root)

    check_output(Path(out), overwrite)
    return atomic_folder(Path(out), fill, "dataset")
