"""`terra sim`: generate a simulated campus dataset with ground truth and a top-down picture."""

from __future__ import annotations

import time
from pathlib import Path

import typer

from terra.cli import app
from terra.cli.interrupts import on_interrupt
from terra.errors import TerraError
from terra.words import counted


@app.command("sim")
def sim(
    out: Path = typer.Option(
        ..., "--out", "-o", help="Output folder (must not exist or be empty, unless --overwrite)."
    ),
    preset: str = typer.Option(
        "small", "--preset", "-p", help="World size: tiny, small, campus, large (2 km) or huge (3.2 km)."
    ),
    seed: int = typer.Option(0, "--seed", "-s", min=0, help="Random seed; same preset and seed give the same bytes."),
    format: str = typer.Option(
        "terra-folder",
        "--format",
        "-f",
        help="terra-folder (the reference layout), semantickitti, kitti-raw (a raw drive with "
        "OXTS; cameras render undistorted), rosbag1 (a ROS 1 .bag) or rosbag2 (a ROS 2 mcap bag).",
    ),
    config: Path | None = typer.Option(
        None, "--config", "-c", help="YAML file with a `sim:` section (see `terra config dump sim`)."
    ),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a non-empty output folder."),
    bag_images: str = typer.Option(
        "jpeg", "--bag-images", help="Images in a bag: jpeg (sensor_msgs/CompressedImage) or raw (Image rgb8)."
    ),
    max_frames: int | None = typer.Option(None, "--max-frames", min=1, help="Stop after this many frames."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar or timing table."),
) -> None:
    """Simulate a campus drive and write it as a dataset.

    Simulate a robot driving through a generated campus and write the dataset.

    Writes the frames (LiDAR scans with per-point labels, camera images with label images, poses, calibration), ground_truth/ (objects, terrain raster, named regions), classes.json and world.png, a top-down picture of the world and the route.

    Example: terra sim --preset small --seed 0 --out campus-small
    """
    from terra.config import TerraConfig
    from terra.progress import StageTimer, working
    from terra.sim.classes import CLASS_COLORS
    from terra.sim.dataset import simulate
    from terra.sim.presets import get_preset
    from terra.sim.writer import FORMATS, check_output, write_dataset
    from terra.viz.world import render_world_png

    get_preset(preset)
    if format not in FORMATS:
        raise TerraError(f"unknown format {format!r}; expected one of: {', '.join(FORMATS)}")
    check_output(out, overwrite)
    on_interrupt(f"nothing was written ({out} is unchanged); run the same command again")
    cfg = TerraConfig.read(config).sim
    if max_frames is not None:
        cfg = cfg.model_copy(update={"route": cfg.route.model_copy(update={"max_frames": max_frames})})
    if format == "kitti-raw":  # KITTI raw images are rectified
        from terra.sim.config import without_distortion

        cfg = without_distortion(cfg)
    timer = StageTimer()
    with timer.stage("world"), working("building the world", not quiet):
        dataset = simulate(preset, seed, cfg)
    dataset.timer = timer

    def picture(root: Path) -> None:
        with timer.stage("picture"):
            traj = dataset.trajectory.T_map_base[:, :2, 3]
            render_world_png(
                dataset.ground_truth(),
                root / "world.png",
                traj,
                CLASS_COLORS,
                title=f"{dataset.name}: {counted(len(dataset), 'frame')}",
            )

    start = time.perf_counter()
    try:
        folder = write_dataset(
            dataset, out, format=format, overwrite=overwrite, progress=not quiet, extra=picture, bag_images=bag_images
        )
    except OSError as exc:  # disk full, permissions: the partial folder is already gone
        raise TerraError(f"{out}: could not write the dataset ({exc.strerror or exc}); nothing was written") from None
    elapsed = time.perf_counter() - start
    timer.add("encode and save", elapsed - sum(v for k, v in timer.seconds.items() if k != "world"))
    gt = dataset.ground_truth()
    typer.echo(
        f"wrote {folder} ({format}): {counted(len(dataset), 'frame')}, {counted(len(gt.objects), 'object')}, "
        f"{len(gt.regions)} named regions, picture world.png"
    )
    if not quiet:
        typer.echo(timer.table("terra sim timing"), err=True)
