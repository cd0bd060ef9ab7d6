"""`terra sim`: generate a simulated campus dataset with ground truth and a top-down picture."""

from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from terra.cli import app
from terra.cli.interrupts import on_interrupt
from terra.errors import TerraError
from terra.words import counted

if TYPE_CHECKING:  # every cli module is imported for `terra --help`: the simulator loads on use
    from terra.progress import StageTimer
    from terra.sim.config import SimConfig
    from terra.sim.dataset import SimDataset
    from terra.sim.results import SimResult

SIM_HELP = """Simulate a campus drive and write it as a dataset.

Simulate a robot driving through a generated campus and write the dataset.

Writes the frames (LiDAR scans with per-point labels, camera images with label images, poses, calibration), ground_truth/ (objects, terrain raster, named regions), classes.json and world.png, a top-down picture of the world and the route.

Example: terra sim --preset small --seed 0 --out campus-small

Example (a second visit of the same campus): terra sim --preset small --seed 0 --revisit --out campus-small-2
"""  # noqa: E501 - the paragraph is one line of help

OutOpt = Annotated[
    Path, typer.Option("--out", "-o", help="Output folder (must not exist or be empty, unless --overwrite).")
]
PresetOpt = Annotated[
    str, typer.Option("--preset", "-p", help="World size: tiny, small, campus, large (2 km) or huge (3.2 km).")
]
SeedOpt = Annotated[
    int, typer.Option("--seed", "-s", min=0, help="Random seed; same preset and seed give the same bytes.")
]
FormatOpt = Annotated[
    str,
    typer.Option(
        "--format",
        "-f",
        help="terra-folder (the reference layout), semantickitti, kitti-raw (a raw drive with "
        "OXTS; cameras render undistorted), rosbag1 (a ROS 1 .bag) or rosbag2 (a ROS 2 mcap bag).",
    ),
]
ConfigOpt = Annotated[
    Path | None, typer.Option("--config", "-c", help="YAML file with a `sim:` section (see `terra config dump sim`).")
]
OverwriteOpt = Annotated[bool, typer.Option("--overwrite", help="Replace a non-empty output folder.")]
BagImagesOpt = Annotated[
    str, typer.Option("--bag-images", help="Images in a bag: jpeg (sensor_msgs/CompressedImage) or raw (Image rgb8).")
]
RevisitOpt = Annotated[
    bool,
    typer.Option(
        "--revisit",
        help="Drive the same world (--preset, --seed) again as a second visit: the route reversed from another "
        "start, poses in another frame, after known changes (cars moved, removed and added, a bench gone, a lawn "
        "turned to dirt, a fence across a sidewalk), set by the config's `sim.revisit` section (defaults: the "
        "frame 50 m and 90 degrees off). Writes revisit.json: the true T_world_session and the list of changes.",
    ),
]
GnssOpt = Annotated[
    float | None,
    typer.Option(
        "--gnss",
        min=0.0,
        help="Carry a GNSS receiver whose fixes err by this many metres (standard deviation per horizontal axis, "
        "per fix; `sim.gnss` sets the rest): writes gnss.csv (a bag: sensor_msgs/NavSatFix on /gnss/fix), which "
        "anchors the drive on the Earth and lets `terra map --into` start from both drives' GNSS.",
    ),
]
GeometryOpt = Annotated[
    bool,
    typer.Option(
        "--geometry",
        help="Build the ground's geometry: 15 cm curbs between roads and everything else with curb cuts where "
        "walkways cross, a ramp beside each flight of stairs, a hill steeper than a wheelchair's limit and gently "
        "sloped lawns (`sim.geometry` sets them; given there, it is on without this flag). The ground truth's "
        "heights carry them.",
    ),
]
MaxFramesOpt = Annotated[int | None, typer.Option("--max-frames", min=1, help="Stop after this many frames.")]
JsonOpt = Annotated[bool, typer.Option("--json", help="Print the summary (counts, timings) as JSON.")]
QuietOpt = Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar or timing table.")]


@app.command("sim", help=SIM_HELP)
def sim(
    out: OutOpt,
    preset: PresetOpt = "small",
    seed: SeedOpt = 0,
    format: FormatOpt = "terra-folder",
    config: ConfigOpt = None,
    overwrite: OverwriteOpt = False,
    bag_images: BagImagesOpt = "jpeg",
    max_frames: MaxFramesOpt = None,
    revisit: RevisitOpt = False,
    gnss: GnssOpt = None,
    geometry: GeometryOpt = False,
    as_json: JsonOpt = False,
    quiet: QuietOpt = False,
) -> None:
    """`terra sim` (its help text: SIM_HELP)."""
    from terra.cli.render import render_sim, render_stage_json
    from terra.progress import StageTimer, working
    from terra.sim.dataset import simulate
    from terra.sim.presets import get_preset
    from terra.sim.writer import check_format, check_output

    get_preset(preset)
    check_format(format)
    check_output(out, overwrite)
    on_interrupt(f"nothing was written ({out} is unchanged); run the same command again")
    cfg = _sim_config(config, max_frames, format, revisit, gnss, geometry)
    timer = StageTimer()
    show = not quiet and not as_json
    with timer.stage("world"), working("building the world", show):
        dataset = simulate(preset, seed, cfg)
    dataset.timer = timer
    result = _write(dataset, out, format, overwrite, show, bag_images, timer)
    typer.echo(render_stage_json(result) if as_json else render_sim(result))
    if not quiet and not as_json:
        typer.echo(timer.table("terra sim timing"), err=True)


def _sim_config(
    config: Path | None,
    max_frames: int | None,
    format: str,
    revisit: bool = False,
    gnss: float | None = None,
    geometry: bool = False,
) -> SimConfig:
    """The `sim` section with --max-frames, --revisit, --gnss and --geometry applied, without lens
    distortion for kitti-raw."""
    from terra.config import TerraConfig
    from terra.sim.config import GeometryConfig, GnssConfig, RevisitConfig

    cfg = TerraConfig.read(config).sim
    if geometry and cfg.geometry is None:
        cfg = cfg.model_copy(update={"geometry": GeometryConfig()})
    if revisit and cfg.revisit is None:
        cfg = cfg.model_copy(update={"revisit": RevisitConfig()})
    elif not revisit and cfg.revisit is not None:
        raise TerraError(f"{config}: sim.revisit is read with --revisit; add it to drive the second visit")
    if gnss is not None:
        if format not in ("terra-folder", "rosbag1", "rosbag2"):
            raise TerraError(
                f"--gnss: GNSS fixes are written to terra-folder datasets (gnss.csv) and bags (NavSatFix), not to "
                f"{format}"
            )
        cfg = cfg.model_copy(update={"gnss": (cfg.gnss or GnssConfig()).model_copy(update={"noise_m": gnss})})
    if max_frames is not None:
        cfg = cfg.model_copy(update={"route": cfg.route.model_copy(update={"max_frames": max_frames})})
    if format == "kitti-raw":  # KITTI raw images are rectified
        from terra.sim.config import without_distortion

        cfg = without_distortion(cfg)
    return cfg


def _write(
    dataset: SimDataset, out: Path, format: str, overwrite: bool, show: bool, bag_images: str, timer: StageTimer
) -> SimResult:
    """Write the dataset and its top-down picture (world.png); what was written."""
    from terra.sim.classes import CLASS_COLORS
    from terra.sim.results import SimResult
    from terra.sim.writer import write_dataset
    from terra.viz.world import render_world_png

    def picture(root: Path) -> None:
        with timer.stage("picture"):
            traj = dataset.trajectory.T_map_base[:, :2, 3]
            title = f"{dataset.name}: {counted(len(dataset), 'frame')}"
            render_world_png(dataset.ground_truth(), root / "world.png", traj, CLASS_COLORS, title=title)
        if dataset.revisit is not None:
            import json

            (root / "revisit.json").write_text(json.dumps(dataset.revisit.to_json(), indent=1) + "\n")

    start = time.perf_counter()
    try:
        folder = write_dataset(
            dataset, out, format=format, overwrite=overwrite, progress=show, extra=picture, bag_images=bag_images
        )
    except OSError as exc:  # disk full, permissions: the partial folder is already gone
        raise TerraError(f"{out}: could not write the dataset ({exc.strerror or exc}); nothing was written") from None
    elapsed = time.perf_counter() - start
    timer.add("encode and save", elapsed - sum(v for k, v in timer.seconds.items() if k != "world"))
    gt = dataset.ground_truth()
    return SimResult(
        folder=Path(folder),
        format=format,
        name=dataset.name,
        frames=len(dataset),
        objects=len(gt.objects),
        regions=len(gt.regions),
        picture="world.png",
        seconds=timer.to_json(),
        timer=timer,
    )
