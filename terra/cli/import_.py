"""`terra import`: the authors' metric-semantic map files in, as a bundle."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from terra.cli import app
from terra.words import counted


@app.command("import")
def import_command(
    folder: Path = typer.Argument(
        ..., help="Output folder of the reference's ms_map (gidx2clipcounts_dict_itrN.pkl, ...)."
    ),
    fmt: str = typer.Option(..., "--format", "-f", help="terra-reference (the only format read)."),
    out: Path = typer.Option(..., "--out", "-o", help="Bundle folder to write."),
    terrain_classes: str | None = typer.Option(
        None, "--terrain-classes", help="Comma-separated class names of the bank's first rows, in order."
    ),
    embedder: str | None = typer.Option(
        None, "--embedder", help="Name of the embedder the files were made with (default clip-vit-b-16)."
    ),
    global_pc: Path | None = typer.Option(
        None,
        "--global-pc",
        help="The dataset's global map (global_pc_T.npy or its folder); default FOLDER/global_pc.",
    ),
    itr: int | None = typer.Option(
        None, "--itr", help="Which save (_itrN) to read (default the largest, as their Phase 2)."
    ),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing bundle."),
    as_json: bool = typer.Option(False, "--json", help="Print the summary as JSON."),
) -> None:
    """Import the authors' metric-semantic map files as a bundle.

    Import the reference's MS-map files as a Terra bundle (then `terra build`, `terra find`).
    Their pickles are read without running code: only plain data is accepted, and torch files load
    with weights only on the CPU (GPU-saved tensors included). Image positions are recovered from
    the files' ranges; see the summary for how.

    Example: terra import ms_map_out -f terra-reference -o field.terra --terrain-classes sidewalk,grass,asphalt
    """
    from terra.cli.interrupts import on_interrupt
    from terra.errors import TerraError
    from terra.interop.reference_import import import_reference

    on_interrupt(f"nothing was written ({out} is unchanged); run the same command again")

    if fmt != "terra-reference":
        raise TerraError(f"--format {fmt!r}: expected terra-reference")
    classes = [c.strip() for c in terrain_classes.split(",") if c.strip()] if terrain_classes is not None else None
    if terrain_classes is not None and not classes:
        raise TerraError("--terrain-classes: give at least one class name, e.g. sidewalk,grass,asphalt")
    from terra.progress import working

    with working("importing", not as_json):
        summary = import_reference(folder, out, classes, embedder, global_pc, itr, overwrite)
    if as_json:
        typer.echo(json.dumps(summary, indent=1, sort_keys=True))
        return
    pos = summary["image_positions"]
    typer.echo(
        f"imported {folder} (itr {summary['itr']}) -> {out}: {counted(summary['points'], 'point')}, "
        f"{summary['observed_points']} with "
        f"object observations, bank {summary['bank']}, {counted(summary['images'], 'image')}, "
        f"embedder {summary['embedder']}"
    )
    typer.echo(f"  terrain classes: {', '.join(summary['terrain_classes'])}")
    typer.echo(
        "  image positions: "
        + ", ".join(f"{k.replace('_', ' ')} {v}" for k, v in pos.items())
        + " (orientation unknown)"
    )
