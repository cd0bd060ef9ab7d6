"""`terra map`: build the metric-semantic map (Phase 1) of a dataset into a bundle."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from terra.cli import app
from terra.errors import TerraError


def _sim_dataset(spec: str):
    preset, _, seed = spec.partition(":")
    try:
        from terra.sim import simulate
    except ImportError:
        raise TerraError("--sim needs the simulator (terra.sim), which is not available") from None
    try:
        return simulate(preset, seed=int(seed) if seed else 0)
    except ValueError as exc:
        raise TerraError(f"--sim {spec!r}: {exc}") from None


@app.command("map")
def map_command(
    dataset: Optional[Path] = typer.Argument(
        None, help="Dataset: a folder (terra-folder, SemanticKITTI) or a ROS bag (.bag, .mcap, ROS 2 bag folder)."),
    out: Path = typer.Option(..., "--out", "-o", help="Bundle folder to write (replaced atomically)."),
    config: Optional[Path] = typer.Option(
        None, "--config", "-c", help="YAML config; its `dataset`, `odometry` and `mapping` sections are used."),
    format: str = typer.Option("auto", "--format", help="Dataset format: auto, terra-folder, semantickitti or rosbag."),
    poses: str = typer.Option("auto", "--poses", help="auto: the source's poses (LiDAR odometry when it has none); "
                                                    "odometry: KISS-ICP on the scans."),
    sim: Optional[str] = typer.Option(None, "--sim", help="Map a simulated campus PRESET[:SEED] instead of a folder."),
    noise: Optional[str] = typer.Option(None, "--noise", help="Perception noise preset (none, realistic); overrides the config."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar or summary."),
) -> None:
    """Build the task-agnostic metric-semantic map of DATASET into the bundle --out.

    An interrupted run resumes from its last checkpoint (OUT.partial/) when rerun with the same
    arguments.

    With a bag, topics and frames need no configuration when the bag makes them unambiguous
    (`terra inspect BAG` prints the `dataset` section it would use). Without poses in the source,
    or with --poses odometry, KISS-ICP computes them and the trajectory is written beside the
    bundle (<name>_poses_kitti.txt, <name>_poses_tum.txt).

    Example: terra map drive.bag --out drive.terra --config terra.yaml
    """
    from terra.config import load_dataset_options, load_section
    from terra.datasets import open_dataset
    from terra.mapping.pipeline import run_mapping
    from terra.odometry.kiss import OdometryDataset, with_poses

    if (dataset is None) == (sim is None):
        raise TerraError("give either a DATASET folder or --sim PRESET[:SEED]")
    overrides = {"perception": {"noise": noise}} if noise is not None else None
    mapping = load_section(config, "mapping", overrides)
    odometry = load_section(config, "odometry")
    source = _sim_dataset(sim) if sim is not None else open_dataset(dataset, format, load_dataset_options(config))
    source = with_poses(source, poses, odometry, show_progress=not quiet)
    run = run_mapping(source, mapping, out, show_progress=not quiet)
    trajectory = None
    if isinstance(source, OdometryDataset):
        from terra.odometry.trajectory import write_trajectory

        trajectory = write_trajectory(out, source.run.stamps, source.run.poses)
    if quiet:
        return
    info = run.bundle.manifest["components"]["map"]
    if run.resumed_from:
        typer.echo(f"resumed after frame {run.resumed_from}")
    typer.echo(
        f"map: {info['points']} points ({info['observed_points']} with object observations), "
        f"{info['bank']} bank entries, {info['images']} images -> {run.bundle.path}"
    )
    if getattr(source, "pose_source", None):
        typer.echo(f"  poses: {source.pose_source}")
    faults = {k: v for k, v in run.stats.items() if ("skipped" in k or "dropped_nonfinite" in k) and v}
    notes = dict(run.notes)
    faults.update(getattr(source, "skipped", {}))  # the source's own: scans without pose or image, undecodable images
    notes.update(getattr(source, "skipped_notes", {}))
    for name, count in faults.items():
        note = notes.get(name)
        typer.echo(f"  {name}: {count}" + (f" (first: {note})" if note else ""))
    if trajectory is not None:
        typer.echo(_odometry_line(source.run, trajectory))
    typer.echo(run.timer.table())


def _odometry_line(run, files) -> str:
    line = (f"odometry: KISS-ICP over {len(run.stamps)} scans ({run.scans_per_second:.1f} scans/s, "
            f"{run.deskewed} deskewed), trajectory -> {files[0]}, {files[1].name}")
    if run.errors:
        e = run.errors
        line += (f"\n  vs the source's poses: ATE {e['ate_rmse_m']:.3f} m RMSE, final error {e['final_error_m']:.3f} m "
                 f"= {e['drift_percent']:.2f} % of {e['distance_m']:.1f} m travelled")
    return line
