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
from terra.words import counted

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
        column = [x for x in (v[col] for v in values) if x is not None]
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


def perception_statement(perception: dict | None, embedder: str = "") -> str:
    """One paragraph saying which perception produced the map and what that means for the tables."""
    if not perception:
        return ""
    backend = perception.get("backend", "unknown")
    if perception.get("ground_truth_masks"):
        noise = perception.get("noise") or {}
        if any(noise.get(k) for k in ("dilate_px", "miss_rate", "confusion_rate")):
            missed, swapped = 100 * (noise.get("miss_rate") or 0), 100 * (noise.get("confusion_rate") or 0)
            how = (
                f"with simulated noise (masks grown by {noise.get('dilate_px', 0)} px, "
                f"{missed:.0f}% of objects missed, "
                f"{swapped:.0f}% of labels swapped for a look-alike)"
            )
        else:
            how = "exactly, without noise"
        return (
            f"Perception: the `labels` backend. Terrain and object masks are the dataset's own ground-truth label "
            f"images, {how}, and class names are embedded as text" + (f" by `{embedder}`" if embedder else "") + ". "
            "Tables I and II therefore grade masks derived from the ground truth itself: they measure the mapping, "
            "fusion and retrieval stages, not a segmenter, and are not comparable with the paper's CLIP/YOLO "
            "numbers. A label lookup has no frame rate, so no FPS is given."
        )
    models = ", ".join(f"{m.get('role', 'model')} `{m.get('name', '?')}`" for m in perception.get("models", []))
    return f"Perception: the `{backend}` backend" + (f" ({models})" if models else "") + "."


def _perception_note(summary: dict) -> list[str]:
    text = perception_statement(summary.get("perception"), summary.get("embedder", ""))
    return [text, ""] if text else []


def _segmentation(seg: dict) -> list[str]:
    methods = ordered(seg.get("methods", {}))
    header = ["Method", "mIoU ↑", "F-mIoU ↑", "F1 ↑", "FPS ↑"]
    keys = ["miou", "fw_miou", "f1", "fps"]
    values = [[m.get(k) for k in keys] for m in methods.values()]
    rows = [[name] + [_f(m.get(k), 1 if k == "fps" else 3) for k in keys] for name, m in methods.items()]
    out = [
        f"## Table I: terrain segmentation ({counted(seg.get('images', 0), 'labelled image')})",
        "",
        table(header, _bold_best(rows, values, [True] * 4)),
        "",
    ]
    if any(m.get("fps") is None for m in methods.values()):
        out += ["FPS: - for a segmenter that is a lookup of label images (no model runs).", ""]
    first = next(iter(methods.values()), None)
    if first:
        names = first["classes"]
        out += [
            "Per-class IoU:",
            "",
            table(["Method"] + names, [[n] + [_f(v) for v in m["iou"]] for n, m in methods.items()]),
            "",
        ]
    return out


def _retrieval(ret: dict) -> list[str]:
    methods = ordered(ret.get("methods", {}))
    header = ["Method", "IoU ↑", "SAcc ↑", "RAcc ↑", "SPrec ↑", "RPrec ↑", "F1 ↑", "matched IoU ↑", "alpha"]
    keys = ["iou", "strict_accuracy", "relaxed_accuracy", "strict_precision", "relaxed_precision", "f1", "matched_iou"]
    values = [[m.get(k) for k in keys] for m in methods.values()]
    rows = [[name] + [_f(m.get(k)) for k in keys] + [_f(m.get("alpha"), 3)] for name, m in methods.items()]
    queries = ret.get("queries", [])
    out = [
        f'## Table II: open-set object retrieval ("{ret.get("template", "Find the {object}")}": '
        f"{counted(ret.get('num_gt', 0), 'object')} in {counted(len(queries), 'query', 'queries')})",
        "",
        table(header, _bold_best(rows, values, [True] * 7)),
        "",
        "IoU divides the matched boxes' IoU by the number of objects; matched IoU is their mean.",
        "",
    ]
    out += _iou_by_distance(methods)
    if methods:
        per = ["Query", "GT"] + [f"{n} found / hits" for n in methods]
        per_rows = []
        for i, q in enumerate(queries):
            row = [q, str(next(iter(methods.values()))["per_query"][i]["num_gt"])]
            for m in methods.values():
                pq = m["per_query"][i]
                row.append(f"{pq['num_predictions']} / {pq['relaxed_hits']}")
            per_rows.append(row)
        out += [
            "Per query. *Found*: the boxes retrieved for the query (clusters of map points that match it better "
            "than any other query or terrain name, above alpha). *Hits*: its ground-truth objects counted as "
            "found by the relaxed-accuracy rule: "
            "the query's best-scoring boxes, as many as it has objects and whichever query they were retrieved "
            "for, are matched one to one to its objects, and a matched box that overlaps its object and holds "
            "its centre is a hit. So a query can have hits with nothing found (its best boxes went to another "
            "query) and boxes found with no hit (a box beside the object, or too thin to overlap it).",
            "",
            table(per, per_rows),
            "",
        ]
    return out


def _iou_by_distance(methods: dict) -> list[str]:
    bands = next((m.get("iou_by_distance") for m in methods.values() if m.get("iou_by_distance")), None)
    if not bands:
        return []
    names = [f"{b['from_m']:g}-{b['to_m']:g} m" if b["to_m"] is not None else f">= {b['from_m']:g} m" for b in bands]
    rows = [
        [n, str(b["objects"])]
        + [
            f"{m['iou_by_distance'][i]['matched']} / {_f(m['iou_by_distance'][i]['matched_iou'], 2)}"
            for m in methods.values()
        ]
        for i, (n, b) in enumerate(zip(names, bands))
    ]
    return [
        "Matched boxes by the objects' distance from the robot's path (matched / their mean IoU):",
        "",
        table(["Distance", "Objects"] + list(methods), rows),
        "",
    ]


def _places(places: dict) -> list[str]:
    rows = []
    for key, label in (("connectivity", "whole raster"), ("connectivity_seen", "ground the cameras labelled")):
        c = places.get(key)
        if c:
            per = ", ".join(f"{t} {v['share']:.3f}" for t, v in c["per_terrain"].items())
            rows.append([label, f"{c['joined']:,} / {c['pairs']:,}", f"{c['joined_share']:.3f}", per])
    regions = ", ".join(f"{k} {v}" for k, v in places.get("places_per_region", {}).items())
    return [
        "## Places against the ground-truth terrain",
        "",
        f"{counted(places.get('places', 0), 'place')}. Pairs of places of one terrain on one connected component of "
        "that terrain "
        "in the ground-truth raster, joined by a path on that terrain alone:",
        "",
        table(["Components over", "Joined pairs", "Share", "per terrain"], rows, "lrrl"),
        "",
        f"Places inside each labelled region: {regions}.",
        "",
    ]


def _regions(reg: dict) -> list[str]:
    methods = ordered(reg.get("methods", {}))
    header = ["Method", "Precision ↑", "Recall ↑", "F1 ↑", "Regions (ms)", "Query (ms)", "Runtime (ms) ↓", "parameters"]
    keys = ["precision", "recall", "f1", "regions_ms", "query_ms", "runtime_ms"]
    values = [[m.get(k) for k in keys] for m in methods.values()]
    rows = [
        [m.get("label", name)] + [_f(m.get(k), 1 if k.endswith("_ms") else 3) for k in keys] + [m.get("parameters", "")]
        for name, m in methods.items()
    ]
    queries = reg.get("queries", [])
    better = [True, True, True, False, False, False]
    skipped = reg.get("not_evaluable", [])
    out = [
        f"## Table III: region monitoring ({counted(len(queries), 'labelled region')}"
        + (f"; {len(skipped)} not evaluable, listed below" if skipped else "")
        + ")",
        "",
        table(header, _bold_best(rows, [v[:3] + [None, None] + v[5:] for v in values], better), "lrrrrrrl"),
        "",
        "Runtime = building the regions (Terra's hierarchy once; AIB's clustering, for every query) + answering one "
        "query, on the same places.",
        "",
    ]
    levels = reg.get("regions_per_level", {})
    if levels:
        out += [
            "Regions per level, level 1 first: "
            + "; ".join(f"{m} {' / '.join(map(str, c))}" for m, c in ordered(levels).items()),
            "",
        ]
    if methods and queries:
        per = ["Region (query)", "GT places"] + [f"{n} P / R" for n in methods]
        per_rows = []
        for i, q in enumerate(queries):
            row = [f'{q["name"]}: "{q["description"]}"', str(q["num_gt_places"])]
            for m in methods.values():
                pq = m["per_query"][i]
                row.append(f"{pq['precision']:.2f} / {pq['recall']:.2f}")
            per_rows.append(row)
        out += ["Per region (precision / recall):", "", table(per, per_rows, "lr" + "r" * len(methods)), ""]
    if skipped:
        out += ["Not evaluable, left out of every average above and of the tuning:", ""]
        out += [f'- {r["name"]}: "{r["description"]}": {r["reason"]}.' for r in skipped] + [""]
    return out


def _memory(mem: dict) -> list[str]:
    parts = mem.get("parts_bytes") or mem.get("components_bytes", {})
    area, total = mem.get("area_m2", 0), mem.get("total_bytes", 0)
    rows = [
        [
            c,
            f"{b:,}",
            f"{b / 2**20:.3f}",
            f"{b / area:,.1f}" if area else "-",
            f"{100 * b / total:.1f}%" if total else "-",
        ]
        for c, b in sorted(parts.items(), key=lambda kv: (-kv[1], kv[0]))
    ]
    rows.append(["**total**", f"{total:,}", f"{total / 2**20:.3f}", f"{total / area:,.1f}" if area else "-", "100%"])
    return [
        "## Memory of the saved map and graph",
        "",
        f"Mapped area {area:,.0f} m² (occupied 0.4 m cells); {mem.get('bytes_per_m2', 0):,.0f} bytes per m² in all.",
        "",
        table(["Part", "Bytes", "MiB", "Bytes per m²", "Share"], rows),
        "",
    ]


def _navigation(nav: dict) -> list[str]:
    plans = ordered(nav.get("plans", {}))
    terrains = sorted({t for p in plans.values() for t in p.get("gt_terrain_m", {})})
    header = ["Plan", "Length (m)", "Places"] + [f"{t} (m, %)" for t in terrains]
    rows = _plan_rows(plans, terrains)
    out = [f'## Navigation: "{nav.get("task", "")}"', ""]
    if nav.get("error"):
        out += [f"Not evaluated: {nav['error']}", ""]
    else:
        skipped = nav.get("skipped", [])
        out += [
            f"Start place {nav.get('start_place')} (nearest the first camera pose), goal place {nav.get('goal_place')} "
            "(the approach place of the best reachable of "
            f"{counted(nav.get('candidates', 1), 'object')} for the task"
            + (f"; {len(skipped)} skipped" if skipped else "")
            + "). Terrain lengths read from the ground-truth raster.",
            "",
            table(header, rows),
            "",
        ]
        out += [
            f"- skipped {s['label']!r} (score {s['score']:.3f}) at place {s['place']}: {s['reason']}" for s in skipped
        ]
        out += [""] if skipped else []
    return out + _preference(nav)


def _plan_rows(plans: dict, terrains: list[str]) -> list[list[str]]:
    rows = []
    for name, p in ordered(plans).items():
        length = p.get("length_m", 0.0)
        rows.append([name, f"{length:.1f}", str(p.get("places", 0))] + [_terrain_cell(p, t, length) for t in terrains])
    return rows


def _terrain_cell(plan: dict, terrain: str, length: float) -> str:
    """ "12.5 (40%)": the metres of a plan's path on `terrain` (ground truth) and their share of its length."""
    metres = plan["gt_terrain_m"].get(terrain, 0.0)
    return f"{metres:.1f} ({100 * metres / length if length else 0:.0f}%)"


def _preference(nav: dict) -> list[str]:
    out = []
    case = nav.get("preference_case")
    if case:
        terrains = sorted({t for p in case["plans"].values() for t in p.get("gt_terrain_m", {})})
        out += [
            f"Terrain preference case: from place {case['start_place']} "
            f"at ({case['start_xy'][0]:.1f}, {case['start_xy'][1]:.1f}) "
            f"to place {case['goal_place']} at ({case['goal_xy'][0]:.1f}, {case['goal_xy'][1]:.1f}) m, the pair of "
            f"{', '.join(nav.get('prefer', []))} places where the preference moves the path most onto it:",
            "",
            table(
                ["Plan", "Length (m)", "Places"] + [f"{t} (m, %)" for t in terrains],
                _plan_rows(case["plans"], terrains),
            ),
            "",
        ]
    routes = nav.get("preference_routes")
    if routes and routes.get("pairs"):
        out += [
            f"Preferring {routes['terrain']} between {routes['pairs']} place pairs "
            f"joined by a {routes['terrain']} route in the world: "
            f"mean {100 * routes['preferred_mean_share']:.1f}% of the path on {routes['terrain']} (shortest: "
            f"{100 * routes['shortest_mean_share']:.1f}%), lowest {100 * routes['preferred_lowest_share']:.1f}%, "
            f"{routes['pairs_meeting']} pairs ({100 * routes['fraction_meeting']:.1f}%) "
            f"at {100 * routes['min_share']:.0f}% or more.",
            "",
        ]
    return out


def _not_evaluated(skipped: dict) -> list[str]:
    titles = {
        "segmentation": "Table I, terrain segmentation",
        "regions": "Table III, region monitoring",
        "navigation": "Navigation",
    }
    out = [
        "## Not evaluated",
        "",
        "The ground truth of this dataset holds objects only (KITTI labels): only Table II "
        "and the memory figures are computed. No number is given for what it cannot score:",
        "",
    ]
    out += [f"- {title}: {skipped[key]}." for key, title in titles.items() if key in skipped]
    out += [f"- {note}." for note in skipped.get("notes", [])]
    return out + [""]


def render_report(summary: dict) -> str:
    """report.md text from a summary dict (see `write_report`)."""
    params = summary.get("parameters", {})
    lines = [
        "# Terra evaluation report",
        "",
        f"- bundle: `{summary.get('bundle', '')}`, ground truth: `{summary.get('dataset', '')}`",
        f"- embedder: `{summary.get('embedder', '')}`; parameters: {params.get('source', 'defaults')}",
        "- runtimes and FPS are measurements on this machine; every other figure is deterministic.",
        "",
    ]
    lines += _perception_note(summary)
    for key, section in (
        ("not_evaluated", _not_evaluated),
        ("segmentation", _segmentation),
        ("retrieval", _retrieval),
        ("regions", _regions),
        ("memory", _memory),
        ("places", _places),
        ("navigation", _navigation),
    ):
        if key in summary:
            lines += section(summary[key])
    figures = dict(sorted(summary.get("figures", {}).items(), key=lambda kv: kv[1]))
    if figures:
        lines += ["## Figures", ""]
        for title, rel in figures.items():
            lines += [f"### {title}", "", f"![{title}]({rel})", ""]
    return "\n".join(lines).rstrip() + "\n"


def terrain_shares(by_terrain: dict[str, float], length: float) -> str:
    """ "sidewalk 60%, grass 40%": each terrain's share of a path's length (metres), largest first."""
    if length <= 0:
        return "no length"
    return ", ".join(
        f"{t} {100 * m / length:.0f}%" for t, m in sorted(by_terrain.items(), key=lambda kv: (-kv[1], kv[0])) if m > 0
    )


def headline(summary: dict) -> list[str]:
    """A few indented lines with the main figures of a summary (printed by `terra eval` and `terra demo`)."""
    nav = summary.get("navigation", {})
    lines = _headline_perception(summary.get("perception"))
    lines += _headline_segmentation(summary.get("segmentation", {}))
    lines += _headline_retrieval(summary.get("retrieval", {}))
    lines += _headline_regions(summary.get("regions", {}))
    lines += _headline_map(summary)
    lines += _headline_paths(nav)
    skipped = [key for key in summary.get("not_evaluated", {}) if key != "notes"]
    if skipped:
        lines.append(f"  not evaluated ({', '.join(skipped)}): the ground truth has objects only (see the report)")
    lines += _headline_preference(nav)
    return lines


def _headline_perception(perception: dict | None) -> list[str]:
    if perception and perception.get("ground_truth_masks"):
        noise = " with simulated noise" if any((perception.get("noise") or {}).values()) else ""
        return [
            f"  perception: labels backend (the ground-truth label images{noise}); terrain segmentation and "
            "retrieval grade masks derived from the ground truth, not comparable with the paper's CLIP/YOLO "
            "figures"
        ]
    if perception:
        return [f"  perception: {perception.get('backend')} backend"]
    return []


def _headline_segmentation(seg: dict) -> list[str]:
    lines = []
    for name, s in ordered(seg.get("methods", {})).items():
        fps = "" if s.get("fps") is None else f", {s['fps']:.0f} FPS"  # no frame rate for a label lookup
        lines.append(f"  terrain segmentation ({name}): mIoU {s['miou']:.3f}, F1 {s['f1']:.3f}{fps}")
    return lines


def _headline_retrieval(ret: dict) -> list[str]:
    lines = []
    for name, s in ordered(ret.get("methods", {})).items():
        counts = f"{counted(ret['num_gt'], 'object')}, {counted(len(ret['queries']), 'query', 'queries')}"
        lines.append(
            f"  retrieval {name:<7} ({counts}): IoU {s['iou']:.3f} "
            f"(matched {s.get('matched_iou', 0.0):.3f}), RAcc {s['relaxed_accuracy']:.3f}, "
            f"RPrec {s['relaxed_precision']:.3f}, F1 {s['f1']:.3f}"
        )
    return lines


def _headline_regions(regions: dict) -> list[str]:
    lines = []
    for name, s in ordered(regions.get("methods", {})).items():
        lines.append(
            f"  regions {name:<13}: P {s['precision']:.3f}, R {s['recall']:.3f}, F1 {s['f1']:.3f}, "
            f"{s['runtime_ms']:.0f} ms "
            f"(regions {s.get('regions_ms', 0.0):.0f} + query {s.get('query_ms', s['runtime_ms']):.0f})"
        )
    skipped_regions = regions.get("not_evaluable", [])
    if skipped_regions:
        lines.append(
            "  regions not evaluable (no place inside, left out of the averages): "
            + ", ".join(r["name"] for r in skipped_regions)
        )
    return lines


def _headline_map(summary: dict) -> list[str]:
    """The places' connectivity and the memory the map and graph take."""
    lines = []
    places = summary.get("places", {}).get("connectivity_seen")
    if places:
        lines.append(
            f"  places: {summary['places']['places']}, same-terrain pairs joined {100 * places['joined_share']:.1f}% "
            "(ground the cameras labelled)"
        )
    mem = summary.get("memory")
    if mem:
        lines.append(
            f"  memory: {mem['total_bytes'] / 2**20:.2f} MiB for {mem['area_m2']:,.0f} m² "
            f"({mem['bytes_per_m2']:.0f} B/m²)"
        )
    return lines


def _headline_paths(nav: dict) -> list[str]:
    lines = []
    for name, p in ordered(nav.get("plans", {})).items():
        lines.append(f"  path {name}: {p['length_m']:.1f} m ({terrain_shares(p['gt_terrain_m'], p['length_m'])})")
    if nav.get("error"):
        lines.append(f"  navigation: {nav['error']}")
    return lines


def _headline_preference(nav: dict) -> list[str]:
    """The preference case's plans and how often preferring a terrain kept routes on it."""
    lines = []
    case = nav.get("preference_case")
    if case:
        for name, p in ordered(case["plans"]).items():
            lines.append(
                f"  case {case['start_place']} -> {case['goal_place']} {name}: {p['length_m']:.1f} m "
                f"({terrain_shares(p['gt_terrain_m'], p['length_m'])})"
            )
    routes = nav.get("preference_routes")
    if routes and routes.get("pairs"):
        lines.append(
            f"  preferring {routes['terrain']} over {routes['pairs']} {routes['terrain']} routes: mean "
            f"{100 * routes['preferred_mean_share']:.1f}% on it, {100 * routes['fraction_meeting']:.1f}% of pairs >= "
            f"{100 * routes['min_share']:.0f}%"
        )
    return lines


def write_report(out: str | Path, summary: dict) -> tuple[Path, Path]:
    """Write `out/summary.json` (canonical JSON) and `out/report.md` rendered from it."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    text = dumps_json(summary)
    atomic_write_bytes(out / SUMMARY, text.encode())
    atomic_write_bytes(out / REPORT, render_report(json.loads(text)).encode())
    return out / SUMMARY, out / REPORT
