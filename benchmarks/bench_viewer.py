"""Viewer start-up and interop speed on one bundle (issue 16: "the campus preset opens in a few
seconds").

Measures, in one process on one bundle: bundle load + viser server up with the whole scene built
(`TerraViewer(...)`), the time a headless Chromium takes from opening the page to showing the
viewer's panel with the scene sent, one find query and one plan through the viewer; and the
exports (spark-dsg, networkx, PLY, terra-reference) and the import back.

Usage: PYTHONPATH=. python benchmarks/bench_viewer.py --bundle campus.terra [--max-points 400000]
Writes benchmarks/results/viewer.json and prints a table.
"""

from __future__ import annotations

import argparse
import os
import platform
import shutil
import tempfile
import time
from pathlib import Path

from benchtable import report


def seconds(fn):
    t0 = time.perf_counter()
    out = fn()
    return time.perf_counter() - t0, out


def viewer_times(bundle: Path, max_points: int, query: str) -> dict:
    from terra.loaded import LoadedBundle
    from terra.viewer.app import TerraViewer, free_port
    from terra.viewer.browser import HeadlessPage, browser_missing

    start, viewer = seconds(
        lambda: TerraViewer(LoadedBundle(bundle), port=free_port("127.0.0.1"), max_points=max_points)
    )
    out = {"server_up_s": start, "points": len(viewer.msm), "points_drawn": int(len(viewer.rows))}
    try:
        out["find_s"], _ = seconds(lambda: viewer.run_query("find", query))  # includes loading the text model
        out["find_warm_s"], _ = seconds(lambda: viewer.run_query("find", query))
        if viewer.graph is not None:
            goal = str(len(viewer.graph.places) - 1)
            out["plan_s"], _ = seconds(lambda: viewer.run_plan("0", goal))
        if browser_missing() is None:
            page_open = time.perf_counter()
            page = HeadlessPage(viewer.url)
            try:
                page.wait_for_text(f"{len(viewer.msm):,} points", timeout=120)
                out["page_shows_scene_s"] = time.perf_counter() - page_open
            finally:
                page.close()
    finally:
        viewer.stop()
    return out


def empty_page_time() -> float:
    """Seconds from opening the page of a viser server with one line of text to seeing it: the
    browser's own start-up, the baseline of the viewer's page time on the same machine and load."""
    import viser

    from terra.viewer.app import free_port
    from terra.viewer.browser import HeadlessPage

    server = viser.ViserServer(host="127.0.0.1", port=free_port("127.0.0.1"), verbose=False)
    server.gui.add_markdown("empty page ready")
    try:
        t0 = time.perf_counter()
        page = HeadlessPage(f"http://127.0.0.1:{server.get_port()}")
        try:
            page.wait_for_text("empty page ready", timeout=120)
            return time.perf_counter() - t0
        finally:
            page.close()
    finally:
        server.stop()


def interop_times(bundle: Path) -> dict:
    from terra.interop.export import export_bundle
    from terra.interop.reference_import import import_reference

    folder = Path(tempfile.mkdtemp(prefix="bench-interop-"))
    out = {}
    try:
        for fmt, name in (
            ("spark-dsg", "g.dsg.json"),
            ("networkx", "g.nx.json"),
            ("ply", "m.ply"),
            ("terra-reference", "ref"),
        ):
            out[f"export_{fmt}_s"], _ = seconds(lambda fmt=fmt, name=name: export_bundle(bundle, fmt, folder / name))
            target = folder / name
            size = (
                sum(p.stat().st_size for p in target.rglob("*") if p.is_file())
                if target.is_dir()
                else target.stat().st_size
            )
            out[f"export_{fmt}_mb"] = size / 2**20
        out["import_terra-reference_s"], _ = seconds(lambda: import_reference(folder / "ref", folder / "back.terra"))
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").partition("\n")[0])
    parser.add_argument("--bundle", type=Path, required=True)
    parser.add_argument("--max-points", type=int, default=200_000)
    parser.add_argument("--query", default="find the dumpster")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "viewer.json")
    args = parser.parse_args()
    result = {
        "bundle": str(args.bundle),
        "machine": platform.platform(),
        "cpus": os.cpu_count(),
        "load_average_1min_at_start": os.getloadavg()[0],
    }
    from terra.viewer.browser import browser_missing

    if browser_missing() is None:
        result["empty_page_s"] = empty_page_time()
    result.update(viewer_times(args.bundle, args.max_points, args.query))
    result.update(interop_times(args.bundle))
    rows = [
        ("points in the map / drawn", f"{result['points']:,} / {result['points_drawn']:,}", "-"),
        ("bundle load + viewer server up", f"{result['server_up_s']:.2f} s", "a few seconds"),
        (
            "page open -> panel and scene shown",
            f"{result.get('page_shows_scene_s', float('nan')):.2f} s",
            "a few seconds",
        ),
        ("same, empty viser page (browser start-up alone)", f"{result.get('empty_page_s', float('nan')):.2f} s", "-"),
        ("find in the viewer (cold text model / warm)", f"{result['find_s']:.2f} / {result['find_warm_s']:.3f} s", "-"),
    ]
    if "plan_s" in result:
        rows.append(("plan in the viewer", f"{result['plan_s']:.3f} s", "-"))
    for fmt in ("spark-dsg", "networkx", "ply", "terra-reference"):
        rows.append((f"export {fmt}", f"{result[f'export_{fmt}_s']:.2f} s, {result[f'export_{fmt}_mb']:.1f} MB", "-"))
    rows.append(("import terra-reference", f"{result['import_terra-reference_s']:.2f} s", "-"))
    report(rows, result, args.out)


if __name__ == "__main__":
    main()
