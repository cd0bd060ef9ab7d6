"""`terra eval`: the paper's evaluation (Tables I-III, memory, navigation) of a bundle against a
simulated dataset's ground truth, `--tune` to choose alpha and k on a validation scene, or
`--terrain-only` for Table I of any terrain segmenters on a labelled dataset."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from terra.cli import app
from terra.errors import TerraError
from terra.words import counted


@app.command("eval")
def eval_command(
    bundle: Path = typer.Argument(
        ...,
        help="Bundle with a map and a scene graph (`terra map`, `terra build`); --terrain-only: a labelled dataset.",
    ),
    gt: Path | None = typer.Option(
        None,
        "--gt",
        help="Dataset folder written by `terra sim` (its ground_truth/ is read), or a KITTI raw drive with labels (retrieval only).",
    ),
    out: Path | None = typer.Option(
        None,
        "--out",
        "-o",
        help="Report folder (report.md, summary.json, figures/); with --tune, where tuned.json goes.",
    ),
    tuned: Path | None = typer.Option(
        None, "--tuned", help="alpha/k chosen on a validation scene (tuned.json from `terra eval --tune`)."
    ),
    tune: bool = typer.Option(
        False, "--tune", help="Grid-search alpha/k on this (validation!) bundle and write OUT/tuned.json."
    ),
    config: list[Path] | None = typer.Option(
        None,
        "--config",
        "-c",
        help="YAML config; its `eval` and `tasks` sections are used (--terrain-only: its mapping.perception, one row each).",
    ),
    terrain_only: bool = typer.Option(
        False,
        "--terrain-only",
        help="Only Table I: each configured terrain segmenter on the labelled images of BUNDLE, a dataset.",
    ),
    dataset_format: str = typer.Option(
        "auto", "--format", help="With --terrain-only: dataset format (auto, terra-folder, semantickitti)."
    ),
    max_images: int | None = typer.Option(
        None,
        "--max-images",
        min=1,
        help="With --terrain-only: images evaluated (default: eval.segmentation.max_images).",
    ),
    overwrite: bool = typer.Option(
        False, "--overwrite", help="Replace an existing report (or tuned.json with --tune)."
    ),
    as_json: bool = typer.Option(False, "--json", help="Print the summary (or the tuned parameters) as JSON."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bars or timing table."),
) -> None:
    """Score a bundle against ground truth (Tables I-III).

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

    Example: terra eval --terrain-only labelled-data --config yolo.yaml --config yoloe.yaml
    """
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
    from terra.cli.interrupts import on_interrupt
    from terra.cli.outputs import refuse_existing
    from terra.config import TerraConfig
    from terra.eval.inputs import EvalInputs
    from terra.eval.runner import evaluate
    from terra.eval.runner import tune as tune_parameters
    from terra.eval.tuning import TUNED, TunedParameters
    from terra.progress import StageTimer

    settings = TerraConfig.read(config)
    eval_cfg, tasks_cfg = settings.eval, settings.tasks
    timer = StageTimer()
    if tune:
        refuse_existing(Path(out) / TUNED, overwrite)
        on_interrupt(f"nothing was written ({Path(out) / TUNED} is unchanged); run the same command again")
        with timer.stage("tune"):
            params = tune_parameters(
                EvalInputs.load(bundle, gt), eval_cfg, tasks_cfg, show_progress=not quiet and not as_json
            )
        path = params.save(Path(out) / TUNED)
        if as_json:
            typer.echo(json.dumps(params.to_json(), indent=1, sort_keys=True))
            return
        typer.echo(f"tuned on {bundle} / {gt}:")
        for name, p in {**params.retrieval, **params.monitoring}.items():
            typer.echo(
                f"  {name}: " + ", ".join(f"{k} {v:g}" if isinstance(v, float) else f"{k} {v}" for k, v in p.items())
            )
        typer.echo(f"wrote {path}")
        if not quiet:
            typer.echo(timer.table())
        return
    params = TunedParameters.load(tuned) if tuned is not None else None
    refuse_existing(Path(out), overwrite)
    on_interrupt(f"no report was written ({out} is unchanged); run the same command again")
    summary = evaluate(
        bundle, gt, out, eval_cfg, params, tasks_cfg, show_progress=not quiet and not as_json, timer=timer
    )
    if as_json:
        typer.echo(json.dumps(summary, indent=1, sort_keys=True))
        return
    typer.echo(f"evaluation of {bundle} against {gt} (parameters: {summary['parameters']['source']}):")
    from terra.eval.report import headline

    for line in headline(summary):
        typer.echo(line)
    typer.echo(f"report: {Path(out) / 'report.md'}")
    if not quiet:
        typer.echo(timer.table())


def _terrain_only(
    dataset_path: Path, configs: list[Path], dataset_format: str, max_images: int | None, as_json: bool, quiet: bool
) -> None:
    """Table I of each configured terrain segmenter on the labelled images of a dataset."""
    from terra.config import TerraConfig
    from terra.datasets import open_dataset
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
    if as_json:
        typer.echo(json.dumps(table, indent=1, sort_keys=True))
        return
    for line in _terrain_lines(table):
        typer.echo(line)
    if not quiet:
        typer.echo(timer.table())


def _terrain_lines(table: dict) -> list[str]:
    """Table I as aligned text: one row per method, then per-class IoU."""
    methods = table["methods"]
    width = max([len(m) for m in methods] + [6])
    lines = [
        f"terrain segmentation of {table['dataset']} ({counted(table['images'], 'labelled image')}):",
        f"  {'method':<{width}}  {'mIoU':>6}  {'F-mIoU':>6}  {'F1':>6}  {'FPS':>7}",
    ]
    for name, s in methods.items():
        fps = "-" if s["fps"] is None else f"{s['fps']:.1f}"  # a label lookup has no frame rate
        lines.append(f"  {name:<{width}}  {s['miou']:>6.3f}  {s['fw_miou']:>6.3f}  {s['f1']:>6.3f}  {fps:>7}")
    for name, s in methods.items():
        per_class = ", ".join(f"{c} {'-' if v is None else f'{v:.3f}'}" for c, v in zip(s["classes"], s["iou"]))
        lines.append(f"  IoU per class, {name}: {per_class}")
    return lines
