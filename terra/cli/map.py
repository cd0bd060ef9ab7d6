"""`terra map`: build the metric-semantic map (Phase 1) of a dataset into a bundle."""

from __future__ import annotations

from pathlib import Path

import typer

from terra.cli import app
from terra.cli.interrupts import on_interrupt
from terra.errors import TerraError
from terra.words import counted


@app.command("map")
def map_command(
    dataset: Path | None = typer.Argument(
        None,
        help="Dataset: a folder (terra-folder, SemanticKITTI, KITTI raw drive) or a ROS bag (.bag, .mcap, ROS 2 bag folder).",
    ),
    out: Path = typer.Option(
        ..., "--out", "-o", help="Bundle folder to write; an existing bundle is kept unless --overwrite."
    ),
    config: Path | None = typer.Option(
        None, "--config", "-c", help="YAML config; its `dataset`, `odometry` and `mapping` sections are used."
    ),
    format: str = typer.Option(
        "auto", "--format", help="Dataset format: auto, terra-folder, semantickitti, kitti-raw or rosbag."
    ),
    camera_config: Path | None = typer.Option(
        None,
        "--camera-config",
        help="The authors' msmap YAML as it is (num_cams, IMG_W, IMG_H, camN_K, camN_dist, cam_axis; other keys ignored) for a terra-folder dataset.",
    ),
    poses: str = typer.Option(
        "auto",
        "--poses",
        help="auto: the source's poses (LiDAR odometry when it has none); odometry: KISS-ICP on the scans.",
    ),
    sim: str | None = typer.Option(None, "--sim", help="Map a simulated campus PRESET[:SEED] instead of a folder."),
    noise: str | None = typer.Option(
        None, "--noise", help="Perception noise preset (none, realistic); overrides the config."
    ),
    perception_only: bool = typer.Option(
        False, "--perception-only", help="Only fill the per-frame perception cache (no fusion, no bundle written)."
    ),
    cache: Path | None = typer.Option(
        None, "--cache", help="Perception cache folder (default OUT.work/perception); overrides the config."
    ),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing bundle at --out (atomically)."),
    workers: int | None = typer.Option(
        None,
        "--workers",
        "-w",
        min=1,
        help="Perceive frames on a local Dask cluster of N worker processes (loopback only); "
        "needs the pip extra 'dask'.",
    ),
    scheduler: str | None = typer.Option(
        None,
        "--scheduler",
        help="Perceive frames on a running Dask cluster: tcp://HOST:PORT or a scheduler file "
        "(default: $TERRA_DASK_SCHEDULER).",
    ),
    in_flight: int | None = typer.Option(
        None,
        "--in-flight",
        min=1,
        help="With a cluster: frames handed out and not yet fused (default: 2 per worker, at least 4).",
    ),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar or summary."),
) -> None:
    """Build the metric-semantic map of a dataset (Phase 1).

    Build the task-agnostic metric-semantic map of DATASET into the bundle --out.

    An existing bundle at --out is refused unless --overwrite. An interrupted run (Ctrl-C, a
    crash) resumes from its last checkpoint (OUT.partial/) when the same command is run again.
    Model outputs (backend `models`) are cached per image in OUT.work/perception/ (or --cache),
    so later runs never repeat inference; --perception-only just fills that cache.

    With a bag, topics and frames need no configuration when the bag makes them unambiguous
    (`terra inspect BAG` prints the `dataset` section it would use). Without poses in the source,
    or with --poses odometry, KISS-ICP computes them and the trajectory is written beside the
    bundle (<name>_poses_kitti.txt, <name>_poses_tum.txt).

    With --workers or --scheduler, Dask workers perceive the frames (each reads them from the same
    path, or renders the same --sim) into the cache, and this process fuses them in order: the same
    bundle, byte for byte. The cache folder must be shared by this process and the workers.

    Example: terra map campus-data --out campus.terra --config terra.yaml

    Example (a ROS bag): terra map drive.bag --out drive.terra

    Example (4 local worker processes): terra map campus-data --out campus.terra --workers 4

    Example (a folder the authors' tools extracted): terra map field-data --camera-config msmap_multicam.yaml --out field.terra
    """
    from terra.config import TerraConfig
    from terra.distributed.cluster import cluster_config
    from terra.odometry.kiss import OdometryDataset, with_poses

    cluster = cluster_config(workers, scheduler, in_flight)
    if in_flight is not None and not cluster.enabled:
        raise TerraError("--in-flight is for a cluster run (--workers or --scheduler)")
    if (dataset is None) == (sim is None):
        raise TerraError("give either a DATASET folder or --sim PRESET[:SEED]")
    if not perception_only:
        _check_out(out, overwrite)
    overrides: dict = {"perception": {}}
    if noise is not None:
        overrides["perception"]["noise"] = noise
    if cache is not None:
        overrides["perception"]["cache"] = {"folder": str(cache)}
    settings = TerraConfig.read(config, {"mapping": overrides})
    mapping, odometry = settings.mapping, settings.odometry
    spec = _source_spec(dataset, sim, format, camera_config, settings.dataset)
    source = with_poses(spec.open(), poses, odometry, show_progress=not quiet)
    if isinstance(source, OdometryDataset):
        spec = spec.with_odometry()  # the workers perceive images, which need no poses
    if perception_only:
        folder = mapping.perception.cache.folder or f"{out}.work/perception"
        on_interrupt(f"the images perceived so far are cached in {folder}; run the same command again to go on")
        _perceive(spec, source, mapping, out, cluster, quiet)
    else:
        on_interrupt(lambda: _kept(out))
        _map(spec, source, mapping, out, cluster, quiet)


def _source_spec(dataset: Path | None, sim: str | None, format: str, camera_config: Path | None, options: dict):
    from terra.distributed.source import SourceSpec

    if camera_config is not None:
        if sim is not None or format not in ("auto", "terra-folder"):
            raise TerraError("--camera-config is for terra-folder datasets (the authors' extracted layout)")
        format, options = "terra-folder", {**options, "camera_config": camera_config}
    return SourceSpec.from_cli(dataset, sim, format, options)


def _map(spec, source, mapping, out: Path, cluster, quiet: bool) -> None:
    from terra.odometry.kiss import OdometryDataset

    if cluster.enabled:
        from terra.distributed.phase1 import map_on_cluster

        run, on_cluster = map_on_cluster(spec, source, mapping, out, cluster, show_progress=not quiet)
    else:
        from terra.mapping.pipeline import run_mapping

        run, on_cluster = run_mapping(source, mapping, out, show_progress=not quiet), None
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
        f"map: {counted(info['points'], 'point')} ({info['observed_points']} with object observations), "
        f"{counted(info['bank'], 'bank entry', 'bank entries')}, {counted(info['images'], 'image')} "
        f"-> {run.bundle.path}"
    )
    if on_cluster is not None:
        _cluster_summary(on_cluster)
    if run.cache is not None:
        cache = run.cache
        where = "removed: the config keeps no cache" if cache.get("removed") else cache["folder"]
        typer.echo(
            f"perception cache: {counted(cache['hits'], 'image')} read back, {cache['computed']} computed ({where})"
        )
    if getattr(source, "pose_source", None):
        typer.echo(f"  poses: {source.pose_source}")
    # The source's own faults too: scans without pose or image, undecodable images.
    _faults({**run.stats, **getattr(source, "skipped", {})}, {**run.notes, **getattr(source, "skipped_notes", {})})
    if trajectory is not None:
        typer.echo(_odometry_line(source.run, trajectory))
    typer.echo(run.timer.table())


def _check_out(out: Path, overwrite: bool) -> None:
    """The common rule (terra.cli.outputs): an existing bundle needs --overwrite; an unfinished run
    (OUT.partial/) resumes."""
    from terra.cli.outputs import refuse_existing

    refuse_existing(out, overwrite)


def _kept(out: Path) -> str:
    """What an interrupted `terra map` leaves: its last checkpoint, to resume from."""
    from terra.bundle import Bundle
    from terra.mapping.checkpoint import Checkpoint

    checkpoint = Checkpoint(out)
    try:
        done = int(Bundle(checkpoint.path).json("state/meta.json")["next_frame"])
    except Exception:  # no checkpoint yet (or an unreadable one, which the next run ignores)
        return f"no checkpoint was reached, {out} is unchanged; run the same command again to start over"
    return f"the map up to frame {done} is checkpointed in {checkpoint.folder}; run the same command again to resume"


def _perceive(spec, source, mapping, out: Path, cluster, quiet: bool) -> None:
    if cluster.enabled:
        from terra.distributed.phase1 import perceive_on_cluster

        run, on_cluster = perceive_on_cluster(spec, source, mapping, out, cluster, show_progress=not quiet)
    else:
        from terra.mapping.perceive import run_perception

        run, on_cluster = run_perception(source, mapping, out, show_progress=not quiet), None
    if quiet:
        return
    if on_cluster is not None:
        _cluster_summary(on_cluster)
    typer.echo(
        f"perception cache: {counted(run.images, 'image')} of {counted(run.frames, 'frame')}, "
        f"{run.hits} already cached, "
        f"{run.computed} computed -> {run.folder}"
    )
    _faults(run.stats, run.notes)
    typer.echo(run.timer.table())


def _cluster_summary(run) -> None:
    tally = run.tally
    used = len(tally.by_worker)
    typer.echo(
        f"perception on {run.cluster}: {counted(tally.frames, 'frame')} by {counted(used, 'worker')} "
        f"(up to {run.in_flight} in flight), {counted(tally.computed, 'image')} computed, {tally.hits} read back, "
        f"{tally.seconds:.1f} s of worker time"
    )


def _faults(stats: dict[str, int], notes: dict[str, str]) -> None:
    faults = {k: v for k, v in stats.items() if ("skipped" in k or "dropped_nonfinite" in k) and v}
    for name, count in faults.items():
        note = notes.get(name)
        typer.echo(f"  {name}: {count}" + (f" (first: {note})" if note else ""))


def _odometry_line(run, files) -> str:
    line = (
        f"odometry: KISS-ICP over {counted(len(run.stamps), 'scan')} ({run.scans_per_second:.1f} scans/s, "
        f"{run.deskewed} deskewed), trajectory -> {files[0]}, {files[1].name}"
    )
    if run.errors:
        e = run.errors
        line += (
            f"\n  vs the source's poses: ATE {e['ate_rmse_m']:.3f} m RMSE, final error {e['final_error_m']:.3f} m "
            f"= {e['drift_percent']:.2f} % of {e['distance_m']:.1f} m travelled"
        )
    return line
