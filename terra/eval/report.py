"""The evaluation report: `summary.json` (every figure, keys named after the metrics) and
`report.md` (tables laid out like the paper's Tables I-III, memory and navigation), rendered from
the summary alone so a report can be re-rendered from its JSON.

Runtimes (`runtime_ms`, `fps`, `timing`) are measurements and vary between runs; every other
value is a deterministic function of the bundle, the ground truth and the configuration.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from terra.bundle import atomic_write_bytes, dumps_json

SUMMARY = "summary.json"
REPORT = "report.md"


# Row order of the tables (the paper's); names not listed follow in sorted order. summary.json is
# canonical JSON with sorted keys, so the order cannot come from the dicts themselves.
ROW_ORDER = ["ms-avg", "ms-max", "3dsg", "aib", "spectral", "agglomerative", "shortest"]


def ordered(rows: dict) -> dict:
    """`rows` re-keyed in ROW_ORDER, then the other keys sorted."""
    rank = {name: i for i, name in enumerate(ROW_ORDER)}
    return {k: rows[k] for k in sorted(rows, key=lambda k: (rank.get(k, len(rank)), k))}


def _f(value: Any, digits: int = 3) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.{digits}f}"
    return str(value)


def _bold_best(rows: list[list[str]], values: list[list[float | None]], higher_better: list[bool]) -> list[list[str]]:
    """Bold the best value of each numeric column (like the paper's tables); ties all bold."""
    out = [list(r) for r in rows]
    for col, better in enumerate(higher_better):
        column = [v[col] for v in values if v[col] is not None]
        if len(column) < 2:
            continue
        best = max(column) if better else min(column)
        for r, v in enumerate(values):
            if v[col] is not None and v[col] == best:
                out[r][col + 1] = f"**{out[r][col + 1]}**"
    return out


def table(header: list[str], rows: list[list[str]], align: str | None = None) -> str:
    """A GitHub-flavoured markdown table; `align` is one of l/r per column (default: l then r)."""
    align = align or "l" + "r" * (len(header) - 1)
    rule = ["---" if a == "l" else "---:" for a in align]
    lines = ["| " + " | ".join(header) + " |", "| " + " | ".join(rule) + " |"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def _segmentation(seg: dict) -> list[str]:
    methods = ordered(seg.get("methods", {}))
    header = ["Method", "mIoU ↑", "F-mIoU ↑", "F1 ↑", "FPS ↑"]
    keys = ["miou", "fw_miou", "f1", "fps"]
    values = [[m.get(k) for k in keys] for m in methods.values()]
    rows = [[name] + [_f(m.get(k), 1 if k == "fps" else 3) for k in keys] for name, m in methods.items()]
    out = [f"## Table I: terrain segmentation ({seg.get('images', 0)} labelled images)", "",
           table(header, _bold_best(rows, values, [True] * 4)), ""]
    first = next(iter(methods.values()), None)
    if first:
        names = first["classes"]
        out += ["Per-class IoU:", "", table(["Method"] + names, [[n] + [_f(v) for v in m["iou"]] for n, m in methods.items()]), ""]
    return out


def _retrieval(ret: dict) -> list[str]:
    methods = ordered(ret.get("methods", {}))
    header = ["Method", "IoU ↑", "SAcc ↑", "RAcc ↑", "SPrec ↑", "RPrec ↑", "F1 ↑", "alpha"]
    keys = ["iou", "strict_accuracy", "relaxed_accuracy", "strict_precision", "relaxed_precision", "f1"]
    values = [[m.get(k) for k in keys] for m in methods.values()]
    rows = [[name] + [_f(m.get(k)) for k in keys] + [_f(m.get("alpha"), 3)] for name, m in methods.items()]
    queries = ret.get("queries", [])
    out = [f"## Table II: open-set object retrieval (\"{ret.get('template', 'Find the {object}')}\": "
           f"{ret.get('num_gt', 0)} objects in {len(queries)} queries)", "",
           table(header, _bold_best(rows, values, [True] * 6)), ""]
    if methods:
        per = ["Query", "GT"] + [f"{n} found / hits" for n in methods]
        per_rows = []
        for i, q in enumerate(queries):
            row = [q, str(next(iter(methods.values()))["per_query"][i]["num_gt"])]
            for m in methods.values():
                pq = m["per_query"][i]
                row.append(f"{pq['num_predictions']} / {pq['relaxed_hits']}")
            per_rows.append(row)
        out += ["Per query (predictions retrieved for the query / relaxed accuracy hits):", "", table(per, per_rows), ""]
    return out


def _regions(reg: dict) -> list[str]:
    methods = ordered(reg.get("methods", {}))
    header = ["Method", "Precision ↑", "Recall ↑", "F1 ↑", "Runtime (ms) ↓", "parameters"]
    keys = ["precision", "recall", "f1", "runtime_ms"]
    values = [[m.get(k) for k in keys] for m in methods.values()]
    rows = [[m.get("label", name)] + [_f(m.get(k), 1 if k == "runtime_ms" else 3) for k in keys] + [m.get("parameters", "")]
            for name, m in methods.items()]
    queries = reg.get("queries", [])
    out = [f"## Table III: region monitoring ({len(queries)} labelled regions)", "",
           table(header, _bold_best(rows, values, [True, True, True, False]), "lrrrrl"), ""]
    if methods and queries:
        per = ["Region (query)", "GT places"] + [f"{n} P / R" for n in methods]
        per_rows = []
        for i, q in enumerate(queries):
            row = [f"{q['name']}: \"{q['description']}\"", str(q["num_gt_places"])]
            for m in methods.values():
                pq = m["per_query"][i]
                row.append(f"{pq['precision']:.2f} / {pq['recall']:.2f}")
            per_rows.append(row)
        out += ["Per region (precision / recall):", "", table(per, per_rows, "lr" + "r" * len(methods)), ""]
    return out


def _memory(mem: dict) -> list[str]:
    comps = mem.get("components_bytes", {})
    rows = [[c, f"{b:,}", f"{b / 2**20:.3f}"] for c, b in comps.items()]
    rows.append(["**total**", f"{mem.get('total_bytes', 0):,}", f"{mem.get('total_bytes', 0) / 2**20:.3f}"])
    return ["## Memory of the saved map and graph", "",
            f"Mapped area {mem.get('area_m2', 0):,.0f} m² (occupied 0.4 m cells); "
            f"{mem.get('bytes_per_m2', 0):,.0f} bytes per m².", "",
            table(["Component", "Bytes", "MiB"], rows), ""]


def _navigation(nav: dict) -> list[str]:
    plans = ordered(nav.get("plans", {}))
    terrains = sorted({t for p in plans.values() for t in p.get("gt_terrain_m", {})})
    header = ["Plan", "Length (m)", "Places"] + [f"{t} (m, %)" for t in terrains]
    rows = []
    for name, p in plans.items():
        length = p.get("length_m", 0.0)
        cells = [f"{p['gt_terrain_m'].get(t, 0.0):.1f} ({100 * p['gt_terrain_m'].get(t, 0.0) / length if length else 0:.0f}%)" for t in terrains]
        rows.append([name, f"{length:.1f}", str(p.get("places", 0))] + cells)
    out = [f"## Navigation: \"{nav.get('task', '')}\"", ""]
    if nav.get("error"):
        return out + [f"Not evaluated: {nav['error']}", ""]
    out += [f"Start place {nav.get('start_place')} (nearest the first camera pose), goal place {nav.get('goal_place')} "
            f"(nearest the best object for the task). Terrain lengths read from the ground-truth raster.", "",
            table(header, rows), ""]
    return out


def _not_evaluated(skipped: dict) -> list[str]:
    titles = {"segmentation": "Table I, terrain segmentation", "regions": "Table III, region monitoring",
              "navigation": "Navigation"}
    out = ["## Not evaluated", "", "The ground truth of this dataset holds objects only (KITTI labels): only Table II "
           "and the memory figures are computed. No number is given for what it cannot score:", ""]
    out += [f"- {title}: {skipped[key]}." for key, title in titles.items() if key in skipped]
    out += [f"- {note}." for note in skipped.get("notes", [])]
    return out + [""]


def render_report(summary: dict) -> str:
    """report.md text from a summary dict (see `write_report`)."""
    params = summary.get("parameters", {})
    lines = [
        "# Terra evaluation report", "",
        f"- bundle: `{summary.get('bundle', '')}`, ground truth: `{summary.get('dataset', '')}`",
        f"- embedder: `{summary.get('embedder', '')}`; parameters: {params.get('source', 'defaults')}",
        "- runtimes and FPS are measurements on this machine; every other figure is deterministic.", "",
    ]
    for key, section in (("not_evaluated", _not_evaluated), ("segmentation", _segmentation), ("retrieval", _retrieval),
                         ("regions", _regions), ("memory", _memory), ("navigation", _navigation)):
        if key in summary:
            lines += section(summary[key])
    figures = dict(sorted(summary.get("figures", {}).items(), key=lambda kv: kv[1]))
    if figures:
        lines += ["## Figures", ""]
        for title, rel in figures.items():
            lines += [f"### {title}", "", f"![{title}]({rel})", ""]
    return "\n".join(lines).rstrip() + "\n"


def terrain_shares(by_terrain: dict[str, float], length: float) -> str:
    """"sidewalk 60%, grass 40%": each terrain's share of a path's length (metres), largest first."""
    if length <= 0:
        return "no length"
    return ", ".join(f"{t} {100 * m / length:.0f}%" for t, m in sorted(by_terrain.items(), key=lambda kv: (-kv[1], kv[0])) if m > 0)


def headline(summary: dict) -> list[str]:
    """A few indented lines with the main figures of a summary (printed by `terra eval` and `terra demo`)."""
    lines = []
    seg = summary.get("segmentation", {}).get("methods", {})
    for name, s in ordered(seg).items():
        fps = "" if s.get("fps") is None else f", {s['fps']:.0f} FPS"  # no frame rate for a label lookup
        lines.append(f"  terrain segmentation ({name}): mIoU {s['miou']:.3f}, F1 {s['f1']:.3f}{fps}")
    ret = summary.get("retrieval", {})
    for name, s in ordered(ret.get("methods", {})).items():
        lines.append(f"  retrieval {name:<7} ({ret['num_gt']} objects, {len(ret['queries'])} queries): IoU {s['iou']:.3f}, "
                     f"RAcc {s['relaxed_accuracy']:.3f}, RPrec {s['relaxed_precision']:.3f}, F1 {s['f1']:.3f}")
    for name, s in ordered(summary.get("regions", {}).get("methods", {})).items():
        lines.append(f"  regions {name:<13}: P {s['precision']:.3f}, R {s['recall']:.3f}, F1 {s['f1']:.3f}, {s['runtime_ms']:.0f} ms/query")
    mem = summary.get("memory")
    if mem:
        lines.append(f"  memory: {mem['total_bytes'] / 2**20:.2f} MiB for {mem['area_m2']:,.0f} m² ({mem['bytes_per_m2']:.0f} B/m²)")
    nav = summary.get("navigation", {})
    for name, p in ordered(nav.get("plans", {})).items():
        lines.append(f"  path {name}: {p['length_m']:.1f} m ({terrain_shares(p['gt_terrain_m'], p['length_m'])})")
    if nav.get("error"):
        lines.append(f"  navigation: {nav['error']}")
    skipped = [key for key in summary.get("not_evaluated", {}) if key != "notes"]
    if skipped:
        lines.append(f"  not evaluated ({', '.join(skipped)}): the ground truth has objects only (see the report)")
    return lines


def write_report(out: str | Path, summary: dict) -> tuple[Path, Path]:
    """Write `out/summary.json` (canonical JSON) and `out/report.md` rendered from it."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    text = dumps_json(summary)
    atomic_write_bytes(out / SUMMARY, text.encode())
    atomic_write_bytes(out / REPORT, render_report(json.loads(text)).encode())
    return out / SUMMARY, out / REPORT
