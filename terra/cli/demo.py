"""`terra demo`: simulate a campus, map it, build its scene graph, run the paper's tasks and
evaluate them, with every step cached under --out (terra.eval.demo)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from terra.cli import app
from terra.cli.interrupts import on_interrupt

OutOpt = Annotated[
    Path,
    typer.Option(
        "--out", "-o", help="Demo folder: scenes, bundles, report/ and demo.json; re-runs reuse what is there."
    ),
]
PresetOpt = Annotated[str, typer.Option("--preset", "-p", help="Test scene: tiny, small, campus or large.")]
SeedOpt = Annotated[
    int, typer.Option("--seed", "-s", min=0, help="Seed of the test scene; the validation scene uses seed + 1.")
]
ValidationPresetOpt = Annotated[
    str | None,
    typer.Option(
        "--validation-preset", help="Preset of the validation scene, where alpha and k are tuned (default: --preset)."
    ),
]
ValidationSpacingOpt = Annotated[
    float,
    typer.Option(
        "--validation-spacing",
        help="The validation scene's frames are this many times further apart than the test scene's "
        "(cheaper; 1 = same).",
    ),
]
FormatOpt = Annotated[
    str,
    typer.Option(
        "--format",
        help="How the scenes are written and read back: terra-folder, rosbag2 (a ROS 2 mcap bag) or rosbag1.",
    ),
]
ConfigOpt = Annotated[
    Path | None,
    typer.Option("--config", "-c", help="YAML config; its sim, mapping, build, tasks and eval sections are used."),
]
OverwriteOpt = Annotated[
    bool, typer.Option("--overwrite", help="Redo every step instead of resuming from the finished ones.")
]
JsonOpt = Annotated[
    bool, typer.Option("--json", help="Print demo.json (tasks, parameters) with the evaluation summary as JSON.")
]
QuietOpt = Annotated[bool, typer.Option("--quiet", "-q", help="No progress bars, step log or timing table.")]
LiveOpt = Annotated[
    bool,
    typer.Option(
        "--live",
        help="Then replay the test drive live (a snapshot every 2 s of drive), asking the plan's target at each "
        "quarter of it, each answer beside the final one (report/live.md).",
    ),
]
SpeedOpt = Annotated[
    float, typer.Option("--speed", min=0.0, help="With --live: times real time (0 = as fast as it maps).")
]


@app.command("demo")
def demo_command(
    out: OutOpt = Path("terra-demo"),
    preset: PresetOpt = "small",
    seed: SeedOpt = 0,
    validation_preset: ValidationPresetOpt = None,
    validation_spacing: ValidationSpacingOpt = 2.0,
    format: FormatOpt = "terra-folder",
    config: ConfigOpt = None,
    overwrite: OverwriteOpt = False,
    as_json: JsonOpt = False,
    quiet: QuietOpt = False,
    live: LiveOpt = False,
    speed: SpeedOpt = 1.0,
) -> None:
    """Run the whole system on a simulated campus and write a report.

    Show the whole system working: simulate the --preset campus (seed --seed) and a validation
    campus (seed + 1), map both, build their scene graphs, choose alpha and k on the validation
    scene, then on the test scene find "Get bike from the bicycle rack" and "Find the dumpster",
    monitor "Large parking lot surrounded by buildings", plan to the bicycle rack preferring
    sidewalk, and evaluate it like the paper (OUT/report/report.md).

    Every step is cached under OUT with the configuration it was made with: a second run, or a
    run after Ctrl-C, reuses the finished steps and redoes only what changed (--overwrite redoes
    them all). A folder that is not a demo folder is refused.

    With --format rosbag2 the simulated drives are written as ROS 2 bags and mapped from them, as a
    robot's own log would be.

    Example: terra demo --out terra-demo --preset small
    """
    from terra.eval.demo import DemoConfig, DemoRun, format_demo

    cfg = DemoConfig.load(config, preset, seed, validation_preset, validation_spacing, format)
    run = DemoRun(
        out,
        cfg,
        show_progress=not quiet and not as_json,
        log=None if quiet or as_json else (lambda line: typer.echo(line, err=True)),
        overwrite=overwrite,
    )
    on_interrupt(run.interrupted)
    demo = run.run()
    replayed = run.live(speed) if live else None
    if as_json:
        extra = {"live": replayed.to_json()} if replayed is not None else {}
        typer.echo(
            json.dumps({**demo, **extra, "steps": run.steps, "timing": run.timer.to_json()}, indent=1, sort_keys=True)
        )
        return
    for line in format_demo(demo, Path(out)):
        typer.echo(line)
    if replayed is not None:
        from terra.live.replay import format_replay

        for line in format_replay(replayed):
            typer.echo(line)
    if not quiet:
        typer.echo(run.timer.table("terra demo timing"), err=True)
