"""`export_bundle`: one entry point for every export format (the CLI's `terra export`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal, get_args

from terra.bundle import Bundle
from terra.errors import TerraError
from terra.interop.results import ExportResult

ExportFormat = Literal["spark-dsg", "networkx", "ply", "terra-reference", "geojson"]
FORMATS: tuple[ExportFormat, ...] = get_args(ExportFormat)  # the one list of export formats
DEFAULT_SUFFIX = {
    "spark-dsg": ".dsg.json",
    "networkx": ".nx.json",
    "ply": ".ply",
    "terra-reference": "-reference",
    "geojson": ".geojson",
}


def default_output(bundle: Path, fmt: str) -> Path:
    """Beside the bundle: campus.terra -> campus.dsg.json, campus.nx.json, campus.ply, campus-reference/."""
    bundle = Path(bundle)
    stem = bundle.name[: -len(bundle.suffix)] if bundle.suffix else bundle.name
    return bundle.parent / f"{stem}{DEFAULT_SUFFIX[fmt]}"


def check_format(fmt: str) -> ExportFormat:
    """`fmt` when it names an export format, else TerraError."""
    for known in FORMATS:
        if fmt == known:
            return known
    raise TerraError(f"--format {fmt!r}: expected one of {', '.join(FORMATS)}")


def export_bundle(
    bundle: str | Path,
    fmt: str,
    out: str | Path | None = None,
    overwrite: bool = False,
    features: bool = True,
    color: str = "terrain",
    image_range: float = 20.0,
    anchor: str | None = None,
    path: str | Path | None = None,
) -> ExportResult:
    """Write bundle `bundle` in format `fmt` to `out` (default: `default_output`); returns a summary.
    TerraError (nothing written) for an unknown format, a bundle of another schema version, a
    missing component, or an existing target without `overwrite`. geojson: `anchor` is the
    --anchor text (LAT,LON[,ALT[,YAW_DEG]]; default the manifest's), `path` a `terra plan --json` file."""
    fmt = check_format(fmt)
    source = Bundle(bundle)
    target = Path(out) if out is not None else default_output(Path(bundle), fmt)
    if target.resolve() == source.path.resolve():
        raise TerraError(f"{target}: is the bundle itself; give another --out")
    if fmt == "geojson":
        from terra.interop.geojson import export_geojson

        return ExportResult.of(export_geojson(source, target, overwrite, anchor, Path(path) if path else None))
    if anchor is not None or path is not None:
        raise TerraError(f"--anchor and --path are options of --format geojson, not {fmt}")
    return ExportResult.of(_export(source, fmt, target, overwrite, features, color, image_range))


def _export(
    source: Bundle, fmt: ExportFormat, target: Path, overwrite: bool, features: bool, color: str, image_range: float
) -> dict[str, Any]:
    """The exporter of `fmt`; its summary."""
    if fmt == "spark-dsg":
        from terra.interop.spark import export_spark_dsg

        return export_spark_dsg(source, target, overwrite, features)
    if fmt == "networkx":
        from terra.interop.node_link import export_node_link

        return export_node_link(source, target, overwrite, features)
    if fmt == "ply":
        from terra.interop.ply import export_ply

        return export_ply(source, target, overwrite, color)
    from terra.interop.reference_export import export_reference

    return export_reference(source, target, overwrite, image_range)
