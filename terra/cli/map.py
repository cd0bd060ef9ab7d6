"""`terra map`: build the metric-semantic map (Phase 1) of a dataset into a bundle."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from terra.cli import app
from terra.cli.interrupts import on_interrupt
from terra.errors import TerraError

if TYPE_CHECKING:  # every cli module is imported for `terra --help`: the mapping modules load on use
    import numpy as np

    from terra.distributed.phase1 import ClusterRun
    from terra.mapping.pipeline import MapRun
    from terra.mapping.results import ClusterSummary, MapResult, OdometrySummary, PerceptionResult
    from terra.odometry.kiss import OdometryRun


DatasetArg = Annotated[
    Path | None,
    typer.Argument(
        help="Dataset: a folder (terra-folder, SemanticKITTI, KITTI raw drive) or a ROS bag "
        "(.bag, .mcap, ROS 2 bag folder).",
    ),
]
OutOpt = Annotated[
    Path | None,
    typer.Option("--out", "-o", help="Bundle folder to write; an existing bundle is kept unless --overwrite."),
]
IntoOpt = Annotated[
    Path | None,
    typer.Option(
        "--into",
        help="Join DATASET (another drive of the same site, its poses in its own frame) as a new session of the map "
        "in this bundle: the drive is registered to the map (GICP from --initial-guess, or from the map frame when "
        "both drives share it), its frames fused in the map frame with their own observation counts. An alignment "
        "that does not converge or overlaps too little is refused (exit 2, the bundle untouched).",
    ),
]
GuessOpt = Annotated[
    str | None,
    typer.Option(
        "--initial-guess",
        metavar="X,Y,YAW",
        help="With --into: where the session's frame lies in the map, roughly: its origin at X, Y metres, its x "
        "axis turned YAW degrees counter-clockwise.",
    ),
]
ConfigOpt = Annotated[
    Path | None,
    typer.Option("--config", "-c", help="YAML config; its `dataset`, `odometry` and `mapping` sections are used."),
]
FormatOpt = Annotated[
    str, typer.Option("--format", help="Dataset format: auto, terra-folder, semantickitti, kitti-raw or rosbag.")
]
CameraConfigOpt = Annotated[
    Path | None,
    typer.Option(
        "--camera-config",
        help="The authors' msmap YAML as it is (num_cams, IMG_W, IMG_H, camN_K, camN_dist, cam_axis; other keys "
        "ignored) for a terra-folder dataset.",
    ),
]
PosesOpt = Annotated[
    str,
    typer.Option(
        "--poses",
        help="auto: the source's poses (LiDAR odometry when it has none); odometry: KISS-ICP on the scans.",
    ),
]
SimOpt = Annotated[str | None, typer.Option("--sim", help="Map a simulated campus PRESET[:SEED] instead of a folder.")]
NoiseOpt = Annotated[
    str | None, typer.Option("--noise", help="Perception noise preset (none, realistic); overrides the config.")
]
PerceptionOnlyOpt = Annotated[
    bool,
    typer.Option("--perception-only", help="Only fill the per-frame perception cache (no fusion, no bundle written)."),
]
CacheOpt = Annotated[
    Path | None,
    typer.Option("--cache", help="Perception cache folder (default OUT.work/perception); overrides the config."),
]
OverwriteOpt = Annotated[bool, typer.Option("--overwrite", help="Replace an existing bundle at --out (atomically).")]
AppendOpt = Annotated[
    bool,
    typer.Option(
        "--append",
        help="Continue the map in --out with the frames of DATASET (its poses in the map's frame), from the "
        "fusion state the bundle keeps: the same map as one run over both. Uses the bundle's mapping "
        "configuration unless --config is given (which must agree with it).",
    ),
]
WorkersOpt = Annotated[
    int | None,
    typer.Option(
        "--workers",
        "-w",
        min=1,
        help="Perceive frames on a local Dask cluster of N worker processes (loopback only); "
        "needs the pip extra 'dask'.",
    ),
]
SchedulerOpt = Annotated[
    str | None,
    typer.Option(
        "--scheduler",
        help="Perceive frames on a running Dask cluster: tcp://HOST:PORT or a scheduler file "
        "(default: $TERRA_DASK_SCHEDULER).",
    ),
]
InFlightOpt = Annotated[
    int | None,
    typer.Option(
        "--in-flight",
        min=1,
        help="With a cluster: frames handed out and not yet fused (default: 2 per worker, at least 4).",
    ),
]
StrictOpt = Annotated[
    bool,
    typer.Option(
        "--strict",
        help="Fail (exit 2, nothing written) when the map would have no image semantics: every image skipped, "
        "e.g. the labels backend on images without labels.",
    ),
]
FollowOpt = Annotated[
    bool,
    typer.Option(
        "--follow",
        help="Keep reading a bag while it is being recorded (a ROS 2 folder, .mcap or .db3; a ROS 1 .bag): each "
        "frame is fused once "
        "its images and pose are in, a version is committed every 5 s (queries read it meanwhile), until the "
        "recorder closes the bag, --idle, or Ctrl-C. The final map equals `terra map` of the finished bag. Any other "
        "DATASET is mapped frame by frame the same way.",
    ),
]
IdleOpt = Annotated[
    float | None,
    typer.Option(
        "--idle",
        min=0.0,
        metavar="SECONDS",
        help="With --follow: the recording has ended once it has not grown for SECONDS.",
    ),
]
JsonOpt = Annotated[bool, typer.Option("--json", help="Print the summary (counts, faults, timings) as JSON.")]
QuietOpt = Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar or summary.")]


MAP_HELP = """Build the metric-semantic map of a dataset (Phase 1).

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

Example (fail rather than write a map without image semantics): terra map drive.bag --out drive.terra --strict

Example (4 local worker processes): terra map campus-data --out campus.terra --workers 4

Example (a second visit joined to the map): terra map visit2 --into campus.terra --initial-guess 50,0,90

Example (a folder the authors' tools extracted): terra map field-data --camera-config msmap_multicam.yaml --out field.terra
"""  # noqa: E501 - an example is one command line


@app.command("map", help=MAP_HELP)
def map_command(
    dataset: DatasetArg = None,
    *,
    out: OutOpt = None,
    into: IntoOpt = None,
    initial_guess: GuessOpt = None,
    config: ConfigOpt = None,
    format: FormatOpt = "auto",
    camera_config: CameraConfigOpt = None,
    poses: PosesOpt = "auto",
    sim: SimOpt = None,
    noise: NoiseOpt = None,
    perception_only: PerceptionOnlyOpt = False,
    cache: CacheOpt = None,
    overwrite: OverwriteOpt = False,
    append: AppendOpt = False,
    workers: WorkersOpt = None,
    scheduler: SchedulerOpt = None,
    in_flight: InFlightOpt = None,
    strict: StrictOpt = False,
    follow: FollowOpt = False,
    idle: IdleOpt = None,
    as_json: JsonOpt = False,
    quiet: QuietOpt = False,
) -> None:
    """`terra map` (its help text: MAP_HELP)."""
    from terra.config import TerraConfig
    from terra.distributed.cluster import cluster_config
    from terra.odometry.kiss import POSE_MODES, OdometryDataset, with_poses

    if poses not in POSE_MODES:
        raise TerraError(f"--poses {poses!r}: expected one of: {', '.join(POSE_MODES)}")
    cluster = cluster_config(workers, scheduler, in_flight)
    _check_options(dataset, sim, in_flight, cluster.enabled, append, overwrite or perception_only)
    out, join = _target(out, into, initial_guess, (append, overwrite, perception_only, cluster.enabled, follow))
    settings = TerraConfig.read(config, {"mapping": _perception_overrides(noise, cache)})
    mapping, odometry = settings.mapping, settings.odometry
    if (append or join is not None) and config is None:
        mapping = _recorded_mapping(out, _perception_overrides(noise, cache))
    if follow or idle is not None:  # a recording read while it grows, through a live session
        how = (sim is None and not perception_only and not cluster.enabled and poses == "auto", overwrite, append)
        return _follow(dataset, out, mapping, settings.dataset, format, idle if follow else -1.0, *how, as_json, quiet)
    spec = _source_spec(dataset, sim, format, camera_config, settings.dataset)
    if poses == "odometry":  # before the source is opened, so its own pose check cannot refuse it
        spec = spec.with_odometry()
    show = not quiet and not as_json
    source = with_poses(spec.open(), poses, odometry, show_progress=show)
    if isinstance(source, OdometryDataset):
        spec = spec.with_odometry()  # the workers perceive images, which need no poses
    if perception_only:
        folder = mapping.perception.cache.folder or f"{out}.work/perception"
        on_interrupt(f"the images perceived so far are cached in {folder}; run the same command again to go on")
        result = _perceive(spec, source, mapping, out, cluster, show)
    else:
        on_interrupt(lambda: _kept(out))
        accept = _refuse_without_semantics if strict else None
        result = _map(spec, source, mapping, out, cluster, show, accept, append, join)
        _warn_without_semantics(result)
    _summary(result, as_json, quiet)


def _summary(result: MapResult | PerceptionResult, as_json: bool, quiet: bool, head: str = "") -> None:
    """The summary on stdout (none with --quiet): the text of cli/render.py after `head`, or JSON."""
    if as_json or not quiet:
        from terra.cli.render import render_map, render_stage_json

        typer.echo(render_stage_json(result) if as_json else head + render_map(result))


def _follow(
    dataset: Path | None,
    out: Path,
    mapping,
    options: dict,
    format: str,
    idle: float | None,
    plain: bool,
    overwrite: bool,
    append: bool,
    as_json: bool,
    quiet: bool,
) -> None:
    """`terra map DATASET --follow`: a ROS recording read while it grows (any other dataset frame
    by frame), fused through a live session that commits a version every 5 s; the summary printed.
    plain: no option that --follow cannot honour (--sim, --perception-only, a cluster, --poses)."""
    from terra.bundle import Bundle
    from terra.datasets.registry import loader_options
    from terra.datasets.ros.follow import FollowedBag, is_recording
    from terra.datasets.rosbag import LOADER, RosbagConfig
    from terra.datasets.stream import DatasetSource
    from terra.live.follow import follow
    from terra.mapping.pipeline import map_counts
    from terra.mapping.results import MapResult, pose_source, source_faults

    if idle is not None and idle < 0:
        raise TerraError("--idle is for --follow")
    if not plain or dataset is None:
        raise TerraError(
            "--follow maps one DATASET in this process: not --sim, --perception-only, a cluster or --poses odometry"
        )
    if format in ("auto", "rosbag") and is_recording(dataset):
        config = loader_options(LOADER, options)
        assert isinstance(config, RosbagConfig)
        source = FollowedBag(dataset, config, idle)
    else:
        source = DatasetSource(_source_spec(dataset, None, format, None, options).open())
        if mapping.fusion.use_global_map and source.dataset.global_map() is not None:
            raise TerraError(
                f"{dataset}: --follow builds the map from frames as they come, not on the dataset's own "
                "global map; set mapping.fusion.use_global_map: false to follow it"
            )
    on_interrupt(lambda: f"the versions committed so far are kept in {out}")
    run = follow(source, out, mapping, resume=append, overwrite=overwrite)
    mapper, inner = run.session.mapper, source.dataset  # the bag as recorded, or the dataset
    result = MapResult(
        bundle=out,
        counts=map_counts(Bundle(out)),
        resumed_from=0,
        cache=None,
        stats={**mapper.stats.to_json(), **source_faults(inner)[0], **run.session.refused.counts},
        notes={**mapper.stats.notes, **source_faults(inner)[1], **run.session.refused.notes},
        seconds=mapper.timer.to_json(),
        pose_source=pose_source(inner),
        timer=mapper.timer,
    )
    ended = getattr(source, "ended_by", None) or "the source's last frame"
    _summary(result, as_json, quiet, f"followed until {ended}: versions {run.versions}\n")


def _check_options(
    dataset: Path | None, sim: str | None, in_flight: int | None, on_cluster: bool, append: bool, replacing: bool
) -> None:
    """One line for options that do not go together (`replacing`: --overwrite or --perception-only)."""
    if in_flight is not None and not on_cluster:
        raise TerraError("--in-flight is for a cluster run (--workers or --scheduler)")
    if (dataset is None) == (sim is None):
        raise TerraError("give either a DATASET folder or --sim PRESET[:SEED]")
    if append and (replacing or on_cluster):
        raise TerraError(
            "--append continues a bundle in this process: not with --overwrite, --perception-only or a cluster"
        )


def _target(
    out: Path | None, into: Path | None, guess: str | None, modes: tuple[bool, bool, bool, bool, bool]
) -> tuple[Path, tuple[np.ndarray | None] | None]:
    """The bundle to write (--out, checked as `_check_out` does unless continuing one, or --into when joining
    a session) and, when joining, (the parsed --initial-guess as T_map_session 4x4, or None,).
    `modes`: --append, --overwrite, --perception-only, a cluster, --follow; none goes with --into."""
    from terra.mapping.align import parse_guess

    append, overwrite, perception_only, cluster, follow = modes
    if into is None:
        if guess is not None:
            raise TerraError("--initial-guess is for --into (joining a session to a map)")
        if out is None:
            raise TerraError("give --out BUNDLE (a new map) or --into BUNDLE (join a session to a map)")
        if not perception_only and not append:
            _check_out(out, overwrite)
        return out, None
    if out is not None:
        raise TerraError("--into writes the joined map into its own bundle: leave --out out")
    if any(modes):
        raise TerraError(
            "--into joins a finished drive in this process: not with --append, --overwrite, "
            "--perception-only, --follow or a cluster"
        )
    return into, (parse_guess(guess) if guess is not None else None,)


def _all_skipped(stats: dict, notes: dict, images: int) -> str | None:
    """What a map lacks when every image was skipped for want of labels (None when not)."""
    skipped = stats.get("images_skipped_no_labels", 0)
    if not skipped or images:
        return None
    first = notes.get("images_skipped_no_labels", "")
    return (
        f"all {skipped} images were skipped ({first}); the map has no image semantics and `terra build` will "
        "find no terrain: map with `perception.backend: models` (examples/models.yaml), or give the bag's label "
        "topics"
    )


def _warn_without_semantics(result: MapResult) -> None:
    """A loud line on stderr when every image was skipped: the map then has no image semantics, and
    `terra build` has no terrain to build places on (even with --quiet or --json)."""
    lacks = _all_skipped(result.stats, result.notes, result.counts.images)
    if lacks:
        typer.echo(f"terra map: warning: {lacks}", err=True)


def _refuse_without_semantics(stats: dict, notes: dict) -> None:
    """--strict: the map is not written when every image was skipped (run_mapping's `accept`)."""
    lacks = _all_skipped(stats, notes, stats.get("images_fused", 0))
    if lacks:
        raise TerraError(f"--strict: {lacks}; nothing was written")


def _perception_overrides(noise: str | None, cache: Path | None) -> dict:
    """--noise and --cache as overrides of the `mapping` section."""
    overrides: dict = {"perception": {}}
    if noise is not None:
        overrides["perception"]["noise"] = noise
    if cache is not None:
        overrides["perception"]["cache"] = {"folder": str(cache)}
    return overrides


def _source_spec(dataset: Path | None, sim: str | None, format: str, camera_config: Path | None, options: dict):
    from terra.distributed.source import SourceSpec

    if camera_config is not None:
        if sim is not None or format not in ("auto", "terra-folder"):
            raise TerraError("--camera-config is for terra-folder datasets (the authors' extracted layout)")
        format, options = "terra-folder", {**options, "camera_config": camera_config}
    return SourceSpec.from_cli(dataset, sim, format, options)


def _recorded_mapping(out: Path, overrides: dict):
    """The mapping configuration the bundle at `out` was fused with (what --append continues), with the
    command line's --noise / --cache applied."""
    from terra.mapping.config import MappingConfig
    from terra.mapping.state import append_base
    from terra.schemas import validate_model

    recorded = append_base(Path(out)).model.components.map
    config = dict(recorded.config) if recorded is not None else {}
    perception = {**config.get("perception", {}), **overrides.get("perception", {})}
    return validate_model({**config, "perception": perception}, MappingConfig, Path(out) / "manifest.json")


def _map(
    spec,
    source,
    mapping,
    out: Path,
    cluster,
    show_progress: bool,
    accept=None,
    append: bool = False,
    join: tuple[np.ndarray | None] | None = None,
) -> MapResult:
    """Map the source into the bundle `out` (on the cluster when one is configured), write the
    odometry trajectory when KISS-ICP made the poses; the typed summary of it all. `accept`: as
    run_mapping's. `join`: (prior T_map_session or None,) to join the source as a new session of `out`."""
    from terra.mapping.results import MapResult, pose_source, source_faults
    from terra.odometry.kiss import OdometryDataset

    session = None
    if join is not None:
        run, session = _join(source, mapping, out, join[0], show_progress, accept)
        on_cluster = None
    elif cluster.enabled:
        from terra.distributed.phase1 import map_on_cluster

        run, on_cluster = map_on_cluster(spec, source, mapping, out, cluster, show_progress, accept)
    else:
        from terra.mapping.pipeline import run_mapping

        run = run_mapping(source, mapping, out, show_progress=show_progress, append=append, accept=accept)
        on_cluster = None
    odometry = None
    if isinstance(source, OdometryDataset):
        odometry = _odometry(out, source.run)
    # The source's own faults too: scans without pose or image, undecodable images.
    skipped, skipped_notes = source_faults(source)
    return MapResult(
        bundle=run.bundle.path,
        counts=run.counts,
        resumed_from=run.resumed_from,
        cache=run.cache,
        stats={**run.stats, **skipped},
        notes={**run.notes, **skipped_notes},
        seconds=run.timer.to_json(),
        pose_source=pose_source(source),
        cluster=_cluster_summary(on_cluster) if on_cluster is not None else None,
        odometry=odometry,
        timer=run.timer,
        session=session,
    )


def _join(source, mapping, out: Path, prior: np.ndarray | None, show_progress: bool, accept) -> tuple[MapRun, dict]:
    """Register `source` to the map in `out` (from `prior`, T_map_session) and fuse it as a new session;
    the run and the session as the manifest now lists it."""
    from terra.mapping.pipeline import run_mapping
    from terra.mapping.sessions import plan_join, session_list
    from terra.progress import StageTimer, working

    timer = StageTimer()
    with timer.stage("align"), working("aligning the session to the map", show_progress):
        plan = plan_join(source, out, prior)
    run = run_mapping(
        plan.frames,
        mapping,
        out,
        show_progress=show_progress,
        timer=timer,
        accept=accept,
        join=plan.alignment.to_json(),
    )
    info = run.bundle.model.components.map
    return run, session_list(list(info.sources or []) if info is not None else [])[-1]


def _check_out(out: Path, overwrite: bool) -> None:
    """The common rule (terra.cli.outputs): a folder that is not a bundle is refused even with
    --overwrite; an existing bundle needs --overwrite; an unfinished run (OUT.partial/) resumes."""
    from terra.cli.outputs import refuse_existing
    from terra.mapping.pipeline import check_output

    check_output(Path(out))
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


def _perceive(spec, source, mapping, out: Path, cluster, show_progress: bool) -> PerceptionResult:
    """Fill the perception cache with every image of the source (on the cluster when configured)."""
    from terra.mapping.results import PerceptionResult

    if cluster.enabled:
        from terra.distributed.phase1 import perceive_on_cluster

        run, on_cluster = perceive_on_cluster(spec, source, mapping, out, cluster, show_progress=show_progress)
    else:
        from terra.mapping.perceive import run_perception

        run, on_cluster = run_perception(source, mapping, out, show_progress=show_progress), None
    return PerceptionResult(
        folder=Path(run.folder),
        frames=run.frames,
        images=run.images,
        hits=run.hits,
        computed=run.computed,
        stats=dict(run.stats),
        notes=dict(run.notes),
        seconds=run.timer.to_json(),
        cluster=_cluster_summary(on_cluster) if on_cluster is not None else None,
        timer=run.timer,
    )


def _cluster_summary(run: ClusterRun) -> ClusterSummary:
    from terra.mapping.results import ClusterSummary

    tally = run.tally
    return ClusterSummary(
        cluster=run.cluster,
        in_flight=run.in_flight,
        frames=tally.frames,
        workers_used=len(tally.by_worker),
        computed=tally.computed,
        hits=tally.hits,
        seconds=tally.seconds,
    )


def _odometry(out: Path, run: OdometryRun) -> OdometrySummary:
    """Write the KISS-ICP trajectory beside the bundle; what the run did."""
    from terra.mapping.results import OdometrySummary
    from terra.odometry.trajectory import write_trajectory

    files = write_trajectory(out, run.stamps, run.poses)
    errors = {str(k): float(v) for k, v in run.errors.items()} if run.errors else None
    return OdometrySummary(len(run.stamps), float(run.scans_per_second), int(run.deskewed), files, errors)
