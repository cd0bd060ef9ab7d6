"""`terra info`: summarise a bundle (map counts, terrain histogram, sizes, scene graph)."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from terra.cli import app
from terra.words import counted


def bundle_summary(path: Path, verify: bool = True) -> dict:
    """The summary `terra info` prints; with `verify`, after checking every file's size and SHA-256
    against the manifest and the map metadata's types (TerraError naming the first damaged file)."""
    from terra.bundle import Bundle
    from terra.mapping.summary import map_summary

    bundle = Bundle(path)
    if verify:
        bundle.verify()  # a damaged file is named (TerraError, exit 2) before anything is summarised
        if bundle.has("map/meta.json"):
            from terra.schemas import MapMeta

            bundle.document("map/meta.json", MapMeta)
    summary = map_summary(bundle)
    summary["files_verified"] = len(bundle.files) if verify else 0
    if bundle.has_component("graph"):
        try:
            from terra.graph.summary import graph_summary
        except ImportError:  # the graph stage may not be installed in this build
            graph_summary = None
        if graph_summary is not None:
            summary["graph"] = graph_summary(bundle)
    return summary


def _lines(summary: dict) -> list[str]:
    version = f", version {summary['version']}" if summary.get("version") else ""
    lines = [f"bundle {summary['path']} ({summary.get('written_by')}{version})"]
    emb = summary.get("embedder") or {}
    lines.append(f"  embedder: {emb.get('name')} ({emb.get('dim')}-d)")
    m = summary.get("map")
    if m:
        lines.append(
            f"  points: {m['points']} ({m['observed_points']} with object observations, "
            f"{m['observations']} observations)"
        )
        lines.append(f"  bank entries: {m['bank_entries']}   images: {m['images']}")
        lines.extend(_source_lines(m))
        lines.append("  terrain points: " + ", ".join(f"{k} {v}" for k, v in m["terrain_points"].items()))
        faults = {k: v for k, v in m.get("stats", {}).items() if "skipped" in k or "nonfinite" in k}
        if any(faults.values()):
            lines.append("  skipped: " + ", ".join(f"{k} {v}" for k, v in faults.items() if v))
    if summary.get("graph"):
        lines.extend(_graph_lines(summary["graph"], summary.get("terrain_classes") or []))
    lines.append("  bytes: " + ", ".join(f"{k} {v:,}" for k, v in sorted(summary["bytes"].items())))
    if summary.get("files_verified"):
        lines.append(
            f"  checksums: {counted(summary['files_verified'], 'file')} checked against the manifest, all intact"
        )
    return lines


def _source_lines(m: dict) -> list[str]:
    """Frames, time span and the sources fused into the map (more than one after --append)."""
    span = m.get("time_span")
    when = f", {span[0]:.3f} .. {span[1]:.3f} s" if span else ""
    lines = [f"  frames: {m['frames']}{when}"] if m.get("frames") is not None else []
    sources = m.get("sources") or []
    if len(sources) > 1:
        lines.append(
            "  sources: " + "; ".join(f"{s['name']} (frames {s['first_frame']}.., {s['frames']})" for s in sources)
        )
    sessions = m.get("sessions") or []
    if len(sessions) > 1:
        from terra.cli.render import session_line

        lines.append(f"  sessions: {len(sessions)}")
        lines.extend(session_line(s, "    ") for s in sessions)
    anchor = m.get("wgs84_anchor")
    if anchor:
        lines.append(
            f"  on the Earth: origin {anchor['lat']:.7f}, {anchor['lon']:.7f} (degrees), {anchor['alt']:.1f} m, "
            f"+x {anchor['yaw_deg']:.2f} deg from east ({anchor['projection']}; {anchor['source']})"
        )
    if m.get("frames") is not None and not m.get("fusion_state"):
        lines.append("  fusion state: not kept (this map cannot be continued with --append)")
    return lines


def _counts(counts: dict) -> str:
    return ", ".join(f"{k} {v}" for k, v in counts.items()) or "none"


def _graph_lines(g: dict, terrain_order: list[str]) -> list[str]:
    """The scene graph part of the summary (terra.graph.summary.graph_summary) as readable lines;
    terrains in the map's terrain-class order."""
    places = g.get("places_per_terrain") or {}
    places = {**{t: places[t] for t in terrain_order if t in places}, **places}
    regions = g.get("regions_per_level") or []
    method = f" ({g['region_method']})" if g.get("region_method") else ""
    stale = (
        f" (built on map version {g.get('map_version') or 0}: run `terra build` to update)" if g.get("stale") else ""
    )
    return [
        f"  graph: {g.get('places')} places, {g.get('place_edges')} place edges, {g.get('objects') or 0} objects"
        + stale,
        "    places per terrain: " + _counts(places),
        "    edges by kind: " + _counts(g.get("edges_by_kind") or {}),
        f"    regions per level{method}, lowest first: " + (", ".join(str(n) for n in regions) or "none"),
        "    place embeddings from: " + _counts(g.get("embedding_source") or {}),
    ]


@app.command("info")
def info_command(
    bundle: Path = typer.Argument(..., help="Bundle folder written by `terra map` / `terra build`."),
    as_json: bool = typer.Option(False, "--json", help="Print the summary as JSON."),
    no_verify: bool = typer.Option(
        False, "--no-verify", help="Skip the checksum check of every file (faster on big maps)."
    ),
) -> None:
    """Summarise a bundle.

    Summarise BUNDLE: points, bank size, images, terrain histogram, bytes per component, and
    the scene graph when there is one. Every file's size and SHA-256 are checked against the
    manifest first (unless --no-verify): a damaged file is named and the exit code is 2.

    Example: terra info campus.terra --json
    """
    summary = bundle_summary(bundle, verify=not no_verify)
    if as_json:
        typer.echo(json.dumps(summary, indent=1, sort_keys=True))
    else:
        typer.echo("\n".join(_lines(summary)))
