"""How Terra's shipped task defaults are chosen: by the demo's own rule, on the demo's validation scene.

The rule (`terra eval --tune`, terra.eval.tuning): on a validation scene (the small preset, seed 1,
frames twice as far apart, realistic perception noise, exactly as `terra demo` makes it), alpha
per retrieval method by the best Table II F1, alpha and k per hierarchy by the best Table III F1
(ties: the first grid point). The shipped defaults are the values tuned for the default methods
(terra.eval.tuning.defaults_from_tuned). This script makes or reuses that scene (the steps of
`terra demo`, cached in --demo), tunes, compares with terra.tasks.config and exits 1 on a mismatch.

Usage: PYTHONPATH=. python benchmarks/bench_defaults.py [--demo DIR]
  --demo   the `terra demo` folder to reuse or fill (default terra-demo, the README's: after
           `terra demo` only the tuning runs; from nothing the validation scene takes ~2 min)
Writes benchmarks/results/defaults.json (read by tests/eval/test_defaults.py) and prints a table.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"


def main() -> None:
    from terra.bundle import dumps_json
    from terra.eval.demo import DemoConfig, DemoRun
    from terra.eval.tuning import TUNED, TunedParameters, defaults_from_tuned, shipped_defaults

    parser = argparse.ArgumentParser(description=(__doc__ or "").partition("\n")[0])
    parser.add_argument("--demo", type=Path, default=Path("terra-demo"))
    args = parser.parse_args()
    config = DemoConfig.load(None, "small", 0)  # the demo's defaults: its validation scene is seed 1
    start = time.perf_counter()
    run = DemoRun(args.demo, config, show_progress=False, log=lambda line: print(line, file=sys.stderr))
    scene, _ = run.validation()
    tuned = TunedParameters.load(scene.bundle.parent / TUNED)
    chosen, shipped = defaults_from_tuned(tuned, config.build.regions.method), shipped_defaults(tuned.embedder)
    result = {
        "validation_scene": {
            "preset": config.validation_preset,
            "seed": config.validation_seed,
            "frame_spacing_factor": config.validation_spacing,
            "noise": "realistic",
            "fingerprint": tuned.validation.get("fingerprint", ""),
        },
        "embedder": tuned.embedder,
        "tuned": tuned.to_json(),
        "chosen": chosen,
        "shipped": shipped,
        "machine": platform.node(),
        "date": time.strftime("%Y-%m-%d"),
        "seconds": round(time.perf_counter() - start, 1),
    }
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "defaults.json").write_text(dumps_json(result))
    print(f"{'default':28} {'tuned':>8} {'shipped':>8}")
    for key in chosen:
        mark = "" if chosen[key] == shipped[key] else "  <- differs"
        print(f"{key:28} {chosen[key]:>8g} {shipped[key]:>8g}{mark}")
    print(json.dumps({"same": chosen == shipped}))
    if chosen != shipped:
        sys.exit(1)


if __name__ == "__main__":
    main()
