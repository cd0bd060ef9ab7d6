"""`terra eval`: the paper's evaluation (Tables I-III, memory, navigation) of a bundle against a
simulated dataset's ground truth, or `--tune` to choose alpha and k on a validation scene."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import typer

from terra.cli import app
from terra.errors import TerraError


@app.command("eval")
def eval_command(
    bundle: Path = typer.Argument(..., help="Bundle with a map and a scene graph (`terra map`, `terra build`)."),
    gt: Path = typer.Option(..., "--gt", help="Dataset folder written by `terra sim` (its ground_truth/ is read)."),
    out: Path = typer.Option(..., "--out", "-o", help="Report folder (report.md, summary.json, figures/); with --tune, where tuned.json goes."),
    tuned: Optional[Path] = typer.Option(None, "--tuned", help="alpha/k chosen on a validation scene (tuned.json from `terra eval --tune`)."),
    tune: bool = typer.Option(False, "--tune", help="Grid-search alpha/k on this (validation!) bundle and write OUT/tuned.json."),
    config: Optional[Path] = typer.Option(None, "--config", "-c", help="YAML config; its `eval` and `tasks` sections are used."),
    as_json: bool = typer.Option(False, "--json", help="Print the summary (or the tuned parameters) as JSON."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bars or timing table."),
) -> None:
    """Evaluate BUNDLE against the ground truth of the simulated dataset --gt, like the paper's
    Tables I-III, memory and navigation figures: writes OUT/report.md, OUT/summary.json and
    OUT/figures/*.png.

    Choose thresholds on a validation scene (another seed), never on the test scene: run
    `terra eval val.terra --gt val-data --tune --out val-report`, then evaluate the test bundle
    with `--tuned val-report/tuned.json`. Without --tuned the tasks stage's defaults are used.

    Example: terra eval campus.terra --gt campus-data --tuned val-report/tuned.json --out report
    """
    from terra.config import load_section
    from terra.eval.runner import EvalInputs, evaluate, tune as tune_parameters
    from terra.eval.tuning import TUNED, TunedParameters
    from terra.progress import StageTimer

    if tune and tuned is not None:
        raise TerraError("--tune chooses parameters and --tuned applies them; give one of them")
    eval_cfg = load_section(config, "eval")
    tasks_cfg = load_section(config, "tasks")
    timer = StageTimer()
    if tune:
        with timer.stage("tune"):
            params = tune_parameters(EvalInputs.load(bundle, gt), eval_cfg, tasks_cfg)
        path = params.save(Path(out) / TUNED)
        if as_json:
            typer.echo(json.dumps(params.to_json(), indent=1, sort_keys=True))
            return
        typer.echo(f"tuned on {bundle} / {gt}:")
        for name, p in {**params.retrieval, **params.monitoring}.items():
            typer.echo(f"  {name}: " + ", ".join(f"{k} {v:g}" if isinstance(v, float) else f"{k} {v}" for k, v in p.items()))
        typer.echo(f"wrote {path}")
        if not quiet:
            typer.echo(timer.table())
        return
    params = TunedParameters.load(tuned) if tuned is not None else None
    summary = evaluate(bundle, gt, out, eval_cfg, params, tasks_cfg, show_progress=not quiet, timer=timer)
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
