"""`terra export`: a bundle out to spark_dsg, networkx, PLY or the authors' map files."""

from __future__ import annotations

from pathlib import Path

import typer

from terra.cli import app

ANCHOR_HELP = (
    "geojson: LAT,LON[,ALT[,YAW_DEG]], the WGS84 position of the map origin and the heading of map +x "
    "(degrees counter-clockwise from east); default the bundle's recorded anchor."
)


@app.command("export")
def export_command(
    bundle: Path = typer.Argument(..., help="Bundle folder (`terra map`, and `terra build` for the graph formats)."),
    fmt: str = typer.Option(..., "--format", "-f", help="spark-dsg | networkx | ply | terra-reference | geojson."),
    out: Path | None = typer.Option(
        None, "--out", "-o", help="Output file (folder for terra-reference); default beside the bundle."
    ),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace an existing output."),
    no_features: bool = typer.Option(
        False, "--no-features", help="spark-dsg/networkx: leave out the embedding vectors."
    ),
    color: str = typer.Option(
        "terrain", "--color", help="ply: colour points by 'terrain' or 'ms-max' (most observed bank entry)."
    ),
    image_range: float = typer.Option(
        20.0, "--image-range", help="terra-reference: metres for gidx2imgs_RANGEm_dict (the paper's 20 m)."
    ),
    anchor: str | None = typer.Option(None, "--anchor", help=ANCHOR_HELP),
    path: Path | None = typer.Option(
        None, "--path", help="geojson: add the path of this `terra plan --json` file as a LineString."
    ),
    as_json: bool = typer.Option(False, "--json", help="Print the summary as JSON."),
) -> None:
    """Export a bundle for other tools (spark-dsg, PLY, ...).

    Export BUNDLE for other tools: the scene graph as spark_dsg JSON (Hydra, Clio) or networkx
    node-link JSON, the map's points as PLY (CloudCompare, Open3D), the metric-semantic map
    files of the authors' Phase 1 (their Phase 2 scripts build on them), or places, regions,
    objects and a planned path as GeoJSON in WGS84 (GIS tools; needs the map's anchor, recorded
    for KITTI raw drives mapped on OXTS, else --anchor). Written atomically; an existing output is
    kept unless --overwrite.

    Example: terra export campus.terra --format spark-dsg --out campus.dsg.json
    Example: terra export campus.terra --format geojson --anchor 47.0,8.0,400 --path plan.json
    """
    from terra.cli.interrupts import on_interrupt
    from terra.interop.export import export_bundle
    from terra.progress import working

    on_interrupt("nothing was written (an existing output is unchanged); run the same command again")

    with working(f"exporting {fmt}", not as_json):
        result = export_bundle(
            bundle,
            fmt,
            out,
            overwrite,
            features=not no_features,
            color=color,
            image_range=image_range,
            anchor=anchor,
            path=path,
        )
    from terra.cli.render import render_export, render_stage_json

    typer.echo(render_stage_json(result) if as_json else render_export(result))
