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
    dataset: Optional[Path] = typer.Argument(None, help="Dataset folder (terra-folder, SemanticKITTI sequence, KITTI raw drive)."),
    out: Path = typer.Option(..., "--out", "-o", help="Bundle folder to write (replaced atomically)."),
    config: Optional[Path] = typer.Option(None, "--config", "-c", help="YAML config; its `mapping` section is used."),
    format: str = typer.Option("auto", "--format", help="Dataset format: auto, terra-folder, semantickitti or kitti-raw."),
    camera_config: Optional[Path] = typer.Option(None, "--camera-config", help="The authors' msmap YAML as it is (num_cams, IMG_W, IMG_H, cam{n}_K, cam{n}_dist, cam_axis; other keys ignored) for a terra-folder dataset."),
    sim: Optional[str] = typer.Option(None, "--sim", help="Map a simulated campus PRESET[:SEED] instead of a folder."),
    noise: Optional[str] = typer.Option(None, "--noise", help="Perception noise preset (none, realistic); overrides the config."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar or summary."),
) -> None:
    """Build the task-agnostic metric-semantic map of DATASET into the bundle --out.

    An interrupted run resumes from its last checkpoint (OUT.partial/) when rerun with the same
    arguments.

    Example: terra map campus-data --out campus.terra --config terra.yaml

    Example (a folder the authors' tools extracted): terra map field-data --camera-config msmap_multicam.yaml --out field.terra
    """
    from terra.config import load_section
    from terra.datasets import open_dataset
    from terra.mapping.pipeline import run_mapping

    if (dataset is None) == (sim is None):
        raise TerraError("give either a DATASET folder or --sim PRESET[:SEED]")
    overrides = {"perception": {"noise": noise}} if noise is not None else None
    mapping = load_section(config, "mapping", overrides)
    options = None
    if camera_config is not None:
        if sim is not None or format not in ("auto", "terra-folder"):
            raise TerraError("--camera-config is for terra-folder datasets (the authors' extracted layout)")
        format, options = "terra-folder", {"camera_config": camera_config}
    source = _sim_dataset(sim) if sim is not None else open_dataset(dataset, format, options)
    run = run_mapping(source, mapping, out, show_progress=not quiet)
    if quiet:
        return
    info = run.bundle.manifest["components"]["map"]
    if run.resumed_from:
        typer.echo(f"resumed after frame {run.resumed_from}")
    typer.echo(
        f"map: {info['points']} points ({info['observed_points']} with object observations), "
        f"{info['bank']} bank entries, {info['images']} images -> {run.bundle.path}"
    )
    faults = {k: v for k, v in run.stats.items() if ("skipped" in k or "dropped_nonfinite" in k) and v}
    for name, count in faults.items():
        note = run.notes.get(name)
        typer.echo(f"  {name}: {count}" + (f" (first: {note})" if note else ""))
    typer.echo(run.timer.table())
