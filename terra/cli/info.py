"""`terra info`: summarise a bundle (map counts, terrain histogram, sizes, scene graph)."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from terra.cli import app


def bundle_summary(path: Path) -> dict:
    from terra.bundle import Bundle
    from terra.mapping.summary import map_summary

    bundle = Bundle(path)
    summary = map_summary(bundle)
    if "graph" in bundle.manifest.get("components", {}):
        try:
            from terra.graph.summary import graph_summary
        except ImportError:  # the graph stage may not be installed in this build
            graph_summary = None
        if graph_summary is not None:
            summary["graph"] = graph_summary(bundle)
    return summary


def _lines(summary: dict) -> list[str]:
    lines = [f"bundle {summary['path']} ({summary.get('written_by')})"]
    emb = summary.get("embedder") or {}
    lines.append(f"  embedder: {emb.get('name')} ({emb.get('dim')}-d)")
    m = summary.get("map")
    if m:
        lines.append(f"  points: {m['points']} ({m['observed_points']} with object observations, {m['observations']} observations)")
        lines.append(f"  bank entries: {m['bank_entries']}   images: {m['images']}")
        lines.append("  terrain points: " + ", ".join(f"{k} {v}" for k, v in m["terrain_points"].items()))
        faults = {k: v for k, v in m.get("stats", {}).items() if "skipped" in k or "nonfinite" in k}
        if any(faults.values()):
            lines.append("  skipped: " + ", ".join(f"{k} {v}" for k, v in faults.items() if v))
    if "graph" in summary:
        lines.append("  graph: " + json.dumps(summary["graph"], sort_keys=True))
    lines.append("  bytes: " + ", ".join(f"{k} {v:,}" for k, v in sorted(summary["bytes"].items())))
    return lines


@app.command("info")
def info_command(
    bundle: Path = typer.Argument(..., help="Bundle folder written by `terra map` / `terra build`."),
    as_json: bool = typer.Option(False, "--json", help="Print the summary as JSON."),
) -> None:
    """Summarise BUNDLE: points, bank size, images, terrain histogram, bytes per component, and
    the scene graph when there is one.

    Example: terra info campus.terra --json
    """
    summary = bundle_summary(bundle)
    if as_json:
        typer.echo(json.dumps(summary, indent=1, sort_keys=True))
    else:
        typer.echo("\n".join(_lines(summary)))
