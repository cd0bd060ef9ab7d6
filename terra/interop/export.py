"""`export_bundle`: one entry point for every export format (the CLI's `terra export`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from terra.bundle import Bundle
from terra.errors import TerraError

FORMATS = ("spark-dsg", "networkx", "ply", "terra-reference")
DEFAULT_SUFFIX = {"spark-dsg": ".dsg.json", "networkx": ".nx.json", "ply": ".ply", "terra-reference": "-reference"}


def default_output(bundle: Path, fmt: str) -> Path:
    """Beside the bundle: campus.terra -> campus.dsg.json, campus.nx.json, campus.ply, campus-reference/."""
    bundle = Path(bundle)
    stem = bundle.name[: -len(bundle.suffix)] if bundle.suffix else bundle.name
    return bundle.parent / f"{stem}{DEFAULT_SUFFIX[fmt]}"


def check_format(fmt: str) -> str:
    if fmt not in FORMATS:
        raise TerraError(f"--format {fmt!r}: expected one of {', '.join(FORMATS)}")
    return fmt


def export_bundle(
    bundle: str | Path,
    fmt: str,
    out: str | Path | None = None,
    overwrite: bool = False,
    features: bool = True,
    color: str = "terrain",
    image_range: float = 20.0,
) -> dict[str, Any]:
    """Write bundle `bundle` in format `fmt` to `out` (default: `default_output`); returns a summary.
    TerraError (nothing written) for an unknown format, a bundle of another schema version, a
    missing component, or an existing target without `overwrite`."""
    check_format(fmt)
    source = Bundle(bundle)
    target = Path(out) if out is not None else default_output(Path(bundle), fmt)
    if target.resolve() == source.path.resolve():
        raise TerraError(f"{target}: is the bundle itself; give another --out")
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
