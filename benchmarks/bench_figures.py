"""Time the evaluation report's figures alone (terra.eval.report_figures.write_figures) on a demo
folder's test scene, for the Terra tree on PYTHONPATH; run it once per tree to compare two trees
side by side on the same machine and scene.

Usage: PYTHONPATH=. python benchmarks/bench_figures.py --demo terra-demo [--preset small --seed 0] [--repeat 2]
                                                      [--json benchmarks/results/figures.json]
Writes the JSON and prints a table (wall and CPU seconds per run, PNG bytes).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from benchtable import report  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").partition("\n")[0])
    parser.add_argument("--demo", type=Path, required=True, help="a folder written by `terra demo`")
    parser.add_argument("--preset", default="small")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument(
        "--json",
        type=Path,
        default=Path(__file__).resolve().parent / "results" / "figures.json",
        help="where to write the JSON (one file per tree when comparing two)",
    )
    args = parser.parse_args()
    load = os.getloadavg()[0]
    import terra
    from terra.eval.config import EvalConfig
    from terra.eval.report_figures import write_figures
    from terra.eval.runner import regions_section, retrieval_section

    try:
        from terra.eval.inputs import EvalInputs
    except ImportError:  # trees from before it moved out of the runner
        from terra.eval.inputs import EvalInputs
    from terra.eval.tuning import TunedParameters

    scene = args.demo / f"{args.preset}-seed{args.seed}"
    inputs = EvalInputs.load(scene / "map.terra", scene / "dataset")
    tuned = TunedParameters.load(args.demo / f"validation-{args.preset}-seed{args.seed + 1}" / "tuned.json")
    summary = json.loads((args.demo / "report" / "summary.json").read_text())
    config = EvalConfig()
    _, task, retrieval = retrieval_section(inputs, config, tuned)
    _, monitoring = regions_section(inputs, config, tuned)
    runs = []
    for _ in range(args.repeat):
        with tempfile.TemporaryDirectory() as out:
            wall, cpu = time.perf_counter(), time.process_time()
            figures = write_figures(Path(out), inputs, summary, task, retrieval, monitoring, config)
            runs.append(
                {
                    "wall_s": round(time.perf_counter() - wall, 2),
                    "cpu_s": round(time.process_time() - cpu, 2),
                    "figures": len(figures),
                    "bytes": sum(p.stat().st_size for p in Path(out).rglob("*.png")),
                }
            )
    result = {
        "tree": Path(terra.__file__).resolve().parents[1].name,
        "scene": scene.name,
        "runs": runs,
        "load_average_1min_at_start": load,
        "cpus": os.cpu_count(),
        "machine": platform.platform(),
    }
    rows = [
        (
            f"write_figures, run {i + 1}",
            f"{r['wall_s']:.1f} s wall, {r['cpu_s']:.1f} s CPU, {r['figures']} PNGs, {r['bytes'] / 2**20:.2f} MiB",
            "-",
        )
        for i, r in enumerate(runs)
    ]
    report(rows, result, args.json)


if __name__ == "__main__":
    main()
