"""`terra build`: build the scene graph (Phase 2) of a bundle's map and add it to the bundle."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from terra.cli import app
from terra.cli.interrupts import on_interrupt
from terra.words import counted


def _check_graph(bundle: Path, overwrite: bool) -> None:
    """The common rule for existing outputs (terra.cli.outputs): a scene graph is replaced only
    with --overwrite."""
    from terra.bundle import Bundle
    from terra.errors import TerraError

    if overwrite or not (Path(bundle) / "manifest.json").is_file():
        return  # a missing or damaged bundle is reported by the build itself
    if Bundle(bundle).has_component("graph"):
        raise TerraError(f"{bundle}: has a scene graph already (pass --overwrite to replace it)")


@app.command("build")
def build_command(
    bundle: Path = typer.Argument(..., help="Bundle folder written by `terra map`."),
    config: Path | None = typer.Option(None, "--config", "-c", help="YAML config; its `build` section is used."),
    regions: str | None = typer.Option(
        None, "--regions", help="Region method: agglomerative or spectral (overrides the config)."
    ),
    cuts: str | None = typer.Option(
        None,
        "--cuts",
        help="Agglomerative cut heights, e.g. 50,100,200,400 (the paper's); default: levels adapted to the map.",
    ),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace the scene graph the bundle already has."),
    as_json: bool = typer.Option(False, "--json", help="Print the summary (counts, stats, timings) as JSON."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar or summary."),
) -> None:
    """Build the scene graph of a bundle's map (Phase 2).

    Build the terrain-aware places and hierarchical regions of BUNDLE's map and store them in
    the bundle as component graph/ (spark_dsg JSON plus embedding arrays). A bundle that already
    has a scene graph is refused unless --overwrite. The bundle is replaced atomically: on any
    error or Ctrl-C it is left as it was.

    Example: terra build campus.terra --regions spectral --config terra.yaml
    (the paper's fixed agglomerative levels: terra build campus.terra --cuts 50,100,200,400)
    """
    from terra.config import TerraConfig
    from terra.errors import TerraError
    from terra.graph.pipeline import run_build

    overrides: dict = {"regions": {}}
    if regions is not None:
        if regions not in ("agglomerative", "spectral"):
            raise TerraError(f"--regions must be 'agglomerative' or 'spectral', got {regions!r}")
        overrides["regions"]["method"] = regions
    if cuts is not None:
        try:
            overrides["regions"]["cuts"] = [float(v) for v in cuts.split(",")]
        except ValueError:
            raise TerraError(f"--cuts expects comma-separated numbers such as 50,100,200,400, got {cuts!r}") from None
    overrides = overrides if overrides["regions"] else None
    section = TerraConfig.read(config, {"build": overrides}).build
    _check_graph(bundle, overwrite)
    on_interrupt(f"{bundle} is unchanged; run the same command again")
    from terra.progress import working

    with working("building the scene graph", not quiet and not as_json):
        result = run_build(bundle, section, show_progress=not quiet and not as_json)
    graph = result.graph
    summary = {
        "bundle": str(bundle),
        "places": len(graph.places),
        "place_edges": int(len(graph.place_edges)),
        "regions_per_level": [len(level) for level in graph.regions],
        "region_method": graph.region_method,
        "stats": result.stats,
        "seconds": result.timer.to_json(),
    }
    if as_json:
        typer.echo(json.dumps(summary, indent=1, sort_keys=True))
        return
    if quiet:
        return
    per_terrain = ", ".join(f"{k} {v}" for k, v in result.stats["places_per_terrain"].items())
    edges = result.stats["edges"]
    typer.echo(f"graph: {counted(summary['places'], 'place')} ({per_terrain}) -> {bundle}")
    typer.echo(
        f"  place edges: {summary['place_edges']} (gvd {edges['gvd']}, cross-terrain {edges['cross_terrain']}, bridge {edges['bridge']})"
    )
    typer.echo(
        f"  regions ({graph.region_method}): " + " / ".join(str(n) for n in summary["regions_per_level"]) + " per level"
    )
    src = result.stats["embedding_source"]
    typer.echo(
        f"  place embeddings: {src['images']} from images, {src['points']} from points, {src['terrain_text']} from the terrain name"
    )
    if src["images"] == 0 and src["points"]:
        typer.echo("  (the map has no images: place embeddings come from the map points instead)")
    cells = result.stats["grid_cells"]
    grid_tiles, tiles = result.stats.get("grid_tiles"), result.stats.get("gvd_tiles")
    if grid_tiles and grid_tiles["one_piece"]:
        grid_where = f"in one piece ({grid_tiles['one_piece']})"
    elif grid_tiles:
        grid_where = (
            f"in {section.tiles.size:g} m tiles ({grid_tiles['windows']} windows, "
            f"overlap up to {grid_tiles['max_overlap_m']:g} m)"
        )
    else:
        grid_where = "in one piece"
    gvd_where = (
        f"in tiles ({tiles['windows']} windows, overlap up to {tiles['max_overlap_m']:g} m)"
        if tiles
        else "in one piece"
    )
    typer.echo(f"  terrain grid: {cells[0]} x {cells[1]} cells, computed {grid_where}; GVD {gvd_where}")
    typer.echo(result.timer.table())
