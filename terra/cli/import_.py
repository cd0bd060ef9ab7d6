"""`terra import`: the authors' metric-semantic map files in, as a bundle."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from terra.cli import app

FolderArg = Annotated[
    Path, typer.Argument(help="Output folder of the reference's ms_map (gidx2clipcounts_dict_itrN.pkl, ...).")
]
FormatOpt = Annotated[str, typer.Option("--format", "-f", help="terra-reference (the only format read).")]
OutOpt = Annotated[Path, typer.Option("--out", "-o", help="Bundle folder to write.")]
TerrainClassesOpt = Annotated[
    str | None,
    typer.Option("--terrain-classes", help="Comma-separated class names of the bank's first rows, in order."),
]
EmbedderOpt = Annotated[
    str | None,
    typer.Option(
        "--embedder",
        help="Name of the embedder the files were made with (default: the sidecar's, else clip-vit-b-16, the "
        "authors' CLIP ViT-B/16, whose weights queries find through TERRA_CLIP_PATH). Vectors of another size "
        "are refused.",
    ),
]
GlobalPcOpt = Annotated[
    Path | None,
    typer.Option(
        "--global-pc", help="The dataset's global map (global_pc_T.npy or its folder); default FOLDER/global_pc."
    ),
]
ItrOpt = Annotated[
    int | None, typer.Option("--itr", help="Which save (_itrN) to read (default the largest, as their Phase 2).")
]
OverwriteOpt = Annotated[bool, typer.Option("--overwrite", help="Replace an existing bundle.")]
JsonOpt = Annotated[bool, typer.Option("--json", help="Print the summary as JSON.")]


@app.command("import")
def import_command(
    folder: FolderArg,
    fmt: FormatOpt,
    out: OutOpt,
    terrain_classes: TerrainClassesOpt = None,
    embedder: EmbedderOpt = None,
    global_pc: GlobalPcOpt = None,
    itr: ItrOpt = None,
    overwrite: OverwriteOpt = False,
    as_json: JsonOpt = False,
) -> None:
    """Import the authors' metric-semantic map files as a bundle.

    Import the reference's MS-map files as a Terra bundle (then `terra build`, `terra find`).
    Their pickles are read without running code: only plain data is accepted, and torch files load
    with weights only on the CPU (GPU-saved tensors included). Image positions are recovered from
    the files' ranges; see the summary for how.

    Example: terra import ms_map_out -f terra-reference -o field.terra --terrain-classes sidewalk,grass,asphalt
    """
    from terra.cli.interrupts import on_interrupt
    from terra.cli.render import render_import, render_stage_json
    from terra.interop.reference_import import import_reference
    from terra.progress import working

    on_interrupt(f"nothing was written ({out} is unchanged); run the same command again")
    classes = _import_flags(fmt, terrain_classes)
    with working("importing", not as_json):
        result = import_reference(folder, out, classes, embedder, global_pc, itr, overwrite)
    typer.echo(render_stage_json(result) if as_json else render_import(result, folder))


def _import_flags(fmt: str, terrain_classes: str | None) -> list[str] | None:
    """--format checked; --terrain-classes as a list of names (None when not given)."""
    from terra.errors import TerraError

    if fmt != "terra-reference":
        raise TerraError(f"--format {fmt!r}: expected terra-reference")
    if terrain_classes is None:
        return None
    classes = [c.strip() for c in terrain_classes.split(",") if c.strip()]
    if not classes:
        raise TerraError("--terrain-classes: give at least one class name, e.g. sidewalk,grass,asphalt")
    return classes
