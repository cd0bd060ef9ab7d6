"""`terra eval`: the paper's evaluation (Tables I-III, memory, navigation) of a bundle against a
simulated dataset's ground truth, `--tune` to choose alpha and k on a validation scene, or
`--terrain-only` for Table I of any terrain segmenters on a labelled dataset, or `--ground-only` for
LiDAR ground segmentation against SemanticKITTI labels."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from terra.cli import app
from terra.errors import TerraError

if TYPE_CHECKING:  # every cli module is imported for `terra --help`: the evaluation loads on use
    from terra.eval.results import EvalResult, GroundTable, TerrainTable, TuneResult

EVAL_HELP = """Score a bundle against ground truth (Tables I-III).

Evaluate BUNDLE against the ground truth of the simulated dataset --gt, like the paper's
Tables I-III, memory and navigation figures: writes OUT/report.md, OUT/summary.json and
OUT/figures/*.png.

A KITTI raw drive with object or tracking labels (label_2/, label_02/) has objects only: its
report gives Table II and memory, and says that terrain and region metrics are not evaluated.

Choose thresholds on a validation scene (another seed), never on the test scene: run
`terra eval val.terra --gt val-data --tune --out val-report`, then evaluate the test bundle
with `--tuned val-report/tuned.json`. Without --tuned the tasks stage's defaults are used.

With --terrain-only, BUNDLE is any labelled dataset folder and each --config's terrain
segmenter (mapping.perception) gets a row of Table I (mIoU, F-mIoU, F1, FPS), e.g. a fine-tuned
YOLO against YOLOE prompts.

Example: terra eval campus.terra --gt campus-data --tuned val-report/tuned.json --out report

With --ground-only, BUNDLE is a SemanticKITTI sequence (velodyne/ and labels/): each labelled
scan's LiDAR ground segmentation (the filter `terra build` runs) is scored against its labels,
ground being road, parking, sidewalk, other-ground, lane-marking and terrain; precision, recall
and F1 pooled over points and as the mean of scans.

Example: terra eval --terrain-only labelled-data --config yolo.yaml --config yoloe.yaml

Example: terra eval --ground-only sequences/08 --max-images 50
"""

BundleArg = Annotated[
    Path,
    typer.Argument(
        help="Bundle with a map and a scene graph (`terra map`, `terra build`); --terrain-only: a labelled dataset.",
    ),
]
GtOpt = Annotated[
    Path | None,
    typer.Option(
        "--gt",
        help="Dataset folder written by `terra sim` (its ground_truth/ is read), or a KITTI raw drive with labels "
        "(retrieval only).",
    ),
]
OutOpt = Annotated[
    Path | None,
    typer.Option(
        "--out", "-o", help="Report folder (report.md, summary.json, figures/); with --tune, where tuned.json goes."
    ),
]
TunedOpt = Annotated[
    Path | None,
    typer.Option("--tuned", help="alpha/k chosen on a validation scene (tuned.json from `terra eval --tune`)."),
]
TuneOpt = Annotated[
    bool, typer.Option("--tune", help="Grid-search alpha/k on this (validation!) bundle and write OUT/tuned.json.")
]
ConfigOpt = Annotated[
    list[Path] | None,
    typer.Option(
        "--config",
        "-c",
        help="YAML config; its `eval` and `tasks` sections are used (--terrain-only: its mapping.perception, "
        "one row each).",
    ),
]
TerrainOnlyOpt = Annotated[
    bool,
    typer.Option(
        "--terrain-only",
        help="Only Table I: each configured terrain segmenter on the labelled images of BUNDLE, a dataset.",
    ),
]
GroundOnlyOpt = Annotated[
    bool,
    typer.Option(
        "--ground-only",
        help="Only LiDAR ground segmentation, scored against the labels of BUNDLE, a SemanticKITTI sequence.",
    ),
]
FormatOpt = Annotated[
    str, typer.Option("--format", help="With --terrain-only: dataset format (auto, terra-folder, semantickitti).")
]
MaxImagesOpt = Annotated[
    int | None,
    typer.Option(
        "--max-images",
        min=1,
        help="With --terrain-only: images evaluated (default: eval.segmentation.max_images); with --ground-only: "
        "scans scored (default: all).",
    ),
]
OverwriteOpt = Annotated[
    bool, typer.Option("--overwrite", help="Replace an existing report (or tuned.json with --tune).")
]
JsonOpt = Annotated[bool, typer.Option("--json", help="Print the summary (or the tuned parameters) as JSON.")]
QuietOpt = Annotated[bool, typer.Option("--quiet", "-q", help="No progress bars or timing table.")]


@app.command("eval", help=EVAL_HELP)
def eval_command(
    bundle: BundleArg,
    gt: GtOpt = None,
    out: OutOpt = None,
    tuned: TunedOpt = None,
    tune: TuneOpt = False,
    config: ConfigOpt = None,
    terrain_only: TerrainOnlyOpt = False,
    ground_only: GroundOnlyOpt = False,
    dataset_format: FormatOpt = "auto",
    max_images: MaxImagesOpt = None,
    overwrite: OverwriteOpt = False,
    as_json: JsonOpt = False,
    quiet: QuietOpt = False,
) -> None:
    """`terra eval` (its help text: EVAL_HELP)."""
    if terrain_only and ground_only:
        raise TerraError("--terrain-only scores camera images and --ground-only LiDAR scans; give one of them")
    if ground_only:
        _ground_only(bundle, max_images, as_json, quiet)
        return
    if terrain_only:
        _terrain_only(bundle, config or [], dataset_format, max_images, as_json, quiet)
        return
    if gt is None or out is None:
        missing = "--gt" if gt is None else "--out"
        raise TerraError(f"{missing} is required (or --terrain-only to evaluate terrain segmentation on a dataset)")
    if config and len(config) > 1:
        raise TerraError("give one --config (several are for --terrain-only, one table row each)")
    if tune and tuned is not None:
        raise TerraError("--tune chooses parameters and --tuned applies them; give one of them")
    _evaluate(bundle, gt, out, tuned, tune, config[0] if config else None, as_json, quiet, overwrite)


def _evaluate(
    bundle: Path,
    gt: Path,
    out: Path,
    tuned: Path | None,
    tune: bool,
    config: Path | None,
    as_json: bool,
    quiet: bool,
    overwrite: bool,
) -> None:
    """The full evaluation, or --tune."""
    from terra.config import TerraConfig
    from terra.progress import StageTimer

    settings = TerraConfig.read(config)
    eval_cfg, tasks_cfg = settings.eval, settings.tasks
    timer = StageTimer()
    if tune:
        _tune(bundle, gt, out, eval_cfg, tasks_cfg, timer, as_json, quiet, overwrite)
    else:
        _report(bundle, gt, out, tuned, eval_cfg, tasks_cfg, timer, as_json, quiet, overwrite)


def _tune(bundle, gt, out: Path, eval_cfg, tasks_cfg, timer, as_json: bool, quiet: bool, overwrite: bool) -> None:
    """--tune: choose alpha and k on this bundle, write OUT/tuned.json and say what was chosen."""
    from terra.cli.interrupts import on_interrupt
    from terra.cli.outputs import refuse_existing
    from terra.eval.inputs import EvalInputs
    from terra.eval.results import TuneResult
    from terra.eval.runner import tune as tune_parameters
    from terra.eval.tuning import TUNED

    refuse_existing(Path(out) / TUNED, overwrite)
    on_interrupt(f"nothing was written ({Path(out) / TUNED} is unchanged); run the same command again")
    with timer.stage("tune"):
        inputs = EvalInputs.load(bundle, gt)
        params = tune_parameters(inputs, eval_cfg, tasks_cfg, show_progress=not quiet and not as_json)
    path = params.save(Path(out) / TUNED)
    _show(TuneResult(params, path, Path(bundle), Path(gt), timer), as_json, quiet)


def _report(
    bundle, gt, out: Path, tuned: Path | None, eval_cfg, tasks_cfg, timer, as_json: bool, quiet: bool, overwrite: bool
) -> None:
    """The evaluation report in OUT and its headline."""
    from terra.cli.interrupts import on_interrupt
    from terra.cli.outputs import refuse_existing
    from terra.eval.runner import evaluate
    from terra.eval.tuning import TunedParameters

    params = TunedParameters.load(tuned) if tuned is not None else None
    refuse_existing(Path(out), overwrite)
    on_interrupt(f"no report was written ({out} is unchanged); run the same command again")
    show = not quiet and not as_json
    result = evaluate(bundle, gt, out, eval_cfg, params, tasks_cfg, show_progress=show, timer=timer)
    _show(result, as_json, quiet)


def _show(result: EvalResult | TuneResult | TerrainTable | GroundTable, as_json: bool, quiet: bool) -> None:
    """The result as JSON, or its text summary with the timing table unless --quiet."""
    from terra.cli.render import render_eval, render_stage_json

    if as_json:
        typer.echo(render_stage_json(result))
        return
    typer.echo(render_eval(result))
    if not quiet and result.timer is not None:
        typer.echo(result.timer.table())


def _terrain_only(
    dataset_path: Path, configs: list[Path], dataset_format: str, max_images: int | None, as_json: bool, quiet: bool
) -> None:
    """Table I of each configured terrain segmenter on the labelled images of a dataset."""
    from terra.config import TerraConfig
    from terra.datasets import open_dataset
    from terra.eval.results import TerrainTable
    from terra.eval.segmentation import terrain_table
    from terra.perception.registry import get_terrain_segmenter
    from terra.progress import StageTimer

    timer = StageTimer()
    dataset = open_dataset(dataset_path, dataset_format)
    settings = {path: TerraConfig.read(path) for path in configs or [None]}
    limit = max_images or next(iter(settings.values())).eval.segmentation.max_images or 40
    segmenters = {}
    with timer.stage("load models"):
        for path, setting in settings.items():
            perception = setting.mapping.perception
            label = f"{Path(path).stem if path else 'defaults'} ({perception.backend})"
            segmenters[label] = (get_terrain_segmenter(perception, dataset.classes), perception.noise.seed)
    with timer.stage("segmentation"):
        table = terrain_table(dataset, segmenters, limit, show_progress=not quiet)
    result = TerrainTable.from_json(table)
    result.timer = timer
    _show(result, as_json, quiet)


def _ground_only(sequence: Path, max_scans: int | None, as_json: bool, quiet: bool) -> None:
    """LiDAR ground segmentation scored against the labels of a SemanticKITTI sequence."""
    from terra.eval.ground_segmentation import ground_table
    from terra.progress import StageTimer

    timer = StageTimer()
    with timer.stage("ground segmentation"):
        result = ground_table(sequence, max_scans=max_scans, show_progress=not quiet and not as_json)
    result.timer = timer
    _show(result, as_json, quiet)
