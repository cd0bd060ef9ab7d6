"""`terra build`: build the scene graph (Phase 2) of a bundle's map and add it to the bundle."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from terra.cli import app
from terra.cli.interrupts import on_interrupt

if TYPE_CHECKING:  # every cli module is imported for `terra --help`: the graph modules load on use
    from terra.graph.config import BuildConfig

BundleArg = Annotated[Path, typer.Argument(help="Bundle folder written by `terra map`.")]
ConfigOpt = Annotated[Path | None, typer.Option("--config", "-c", help="YAML config; its `build` section is used.")]
RegionsOpt = Annotated[
    str | None, typer.Option("--regions", help="Region method: agglomerative or spectral (overrides the config).")
]
CutsOpt = Annotated[
    str | None,
    typer.Option(
        "--cuts",
        help="Agglomerative cut heights, e.g. 50,100,200,400 (the paper's); default: levels adapted to the map.",
    ),
]


OverwriteOpt = Annotated[bool, typer.Option("--overwrite", help="Replace the scene graph the bundle already has.")]
JsonOpt = Annotated[bool, typer.Option("--json", help="Print the summary (counts, stats, timings) as JSON.")]
QuietOpt = Annotated[bool, typer.Option("--quiet", "-q", help="No progress bar or summary.")]


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
    bundle: BundleArg,
    config: ConfigOpt = None,
    regions: RegionsOpt = None,
    cuts: CutsOpt = None,
    overwrite: OverwriteOpt = False,
    as_json: JsonOpt = False,
    quiet: QuietOpt = False,
) -> None:
    """Build the scene graph of a bundle's map (Phase 2).

    Build the terrain-aware places and hierarchical regions of BUNDLE's map and store them in
    the bundle as component graph/ (spark_dsg JSON plus embedding arrays). A bundle that already
    has a scene graph is refused unless --overwrite. The bundle is replaced atomically: on any
    error or Ctrl-C it is left as it was.

    Example: terra build campus.terra --regions spectral --config terra.yaml
    (the paper's fixed agglomerative levels: terra build campus.terra --cuts 50,100,200,400)
    """
    from terra.cli.render import render_build, render_stage_json
    from terra.graph.pipeline import run_build
    from terra.graph.results import BuildResult
    from terra.progress import working

    section = _build_section(config, regions, cuts)
    _check_graph(bundle, overwrite)
    on_interrupt(f"{bundle} is unchanged; run the same command again")
    show = not quiet and not as_json
    with working("building the scene graph", show):
        build = run_build(bundle, section, show_progress=show)
    result = BuildResult.of(bundle, build.graph, build.stats, build.timer, section.tiles.size)
    if as_json or not quiet:
        typer.echo(render_stage_json(result) if as_json else render_build(result))


def _build_section(config: Path | None, regions: str | None, cuts: str | None) -> BuildConfig:
    """The `build` section of the config with --regions and --cuts applied (each checked here)."""
    from terra.config import TerraConfig
    from terra.errors import TerraError
    from terra.graph.config import check_region_method

    overrides: dict = {"regions": {}}
    if regions is not None:
        overrides["regions"]["method"] = check_region_method(regions)
    if cuts is not None:
        try:
            overrides["regions"]["cuts"] = [float(v) for v in cuts.split(",")]
        except ValueError:
            raise TerraError(f"--cuts expects comma-separated numbers such as 50,100,200,400, got {cuts!r}") from None
    return TerraConfig.read(config, {"build": overrides} if overrides["regions"] else None).build
