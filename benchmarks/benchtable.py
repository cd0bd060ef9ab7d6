"""The output every benchmark script shares: an aligned table of (measure, value, target) rows
on stdout and the full result as JSON."""

from __future__ import annotations

import json
from pathlib import Path


def report(rows: list[tuple[str, str, str]], result: dict, out: Path) -> None:
    """Print `rows` under a header naming the machine's load, then write `result` to `out`."""
    width = max(len(r[0]) for r in rows)
    value_width = max(len(r[1]) for r in rows)
    print(
        f"{'measure':<{width}}  {'value':<{value_width}}  target   (load average at start "
        f"{result['load_average_1min_at_start']:.1f} on {result['cpus']} cpus)"
    )
    for name, value, target in rows:
        print(f"{name:<{width}}  {value:<{value_width}}  {target}")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(result, indent=1, sort_keys=True) + "\n")
    print(f"wrote {out}")
