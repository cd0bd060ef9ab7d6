"""Start-up of the command line: wall time and import time of `terra --help`, `terra info`, a cold
`terra find` and `terra build` on a mapped campus, this checkout side by side with an earlier commit.

Each command runs as a fresh process (`python -m terra ...` from the root of each tree, so that
tree's package is the one imported), the two trees alternating run by run so that the machine's
load falls on both alike. Import time is the sum of the top-level imports that
`python -X importtime` reports for the same command (the interpreter's own start-up excluded).
`terra build` runs on a copy of the bundle per tree with `build.grid.cell_size: 1.0` (the
authors' `og_resolution`) and `--overwrite`; both trees must give the same places, edges and
regions, which the script checks.

Usage:
  python benchmarks/bench_startup.py --bundle campus.terra [--baseline COMMIT] [--runs 7]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from benchtable import report  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
INTERPRETER_START = {"site", "encodings", "_frozen_importlib_external", "zipimport", "codecs", "io", "abc"}


def unpack(commit: str, into: Path) -> Path:
    """The tree of `commit` (git archive) under `into`."""
    tree = into / f"tree-{commit[:12]}"
    if tree.exists():
        return tree
    tree.mkdir(parents=True)
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", commit, "terra"], capture_output=True, check=True)
    tar_path = into / "tree.tar"
    tar_path.write_bytes(archive.stdout)
    with tarfile.open(tar_path) as tar:
        tar.extractall(tree, filter="data")
    tar_path.unlink()
    return tree


def import_seconds(stderr: str) -> float:
    """Seconds of the top-level imports in `python -X importtime` output (cumulative column)."""
    total_us = 0
    for line in stderr.splitlines():
        if not line.startswith("import time:") or "|" not in line:
            continue
        _, cumulative, name = (part for part in line.split("|"))
        if name.startswith(" ") and not name.startswith("  "):  # one space: a top-level import
            module = name.strip()
            if module.split(".")[0] not in INTERPRETER_START and cumulative.strip().isdigit():
                total_us += int(cumulative.strip())
    return total_us / 1e6


def run_once(tree: Path, args: list[str]) -> tuple[float, float]:
    """(wall seconds, import seconds) of `python -m terra ARGS` from `tree`."""
    env = {**os.environ, "TERRA_PROGRESS": "off", "PYTHONDONTWRITEBYTECODE": "0"}
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "terra", *args], cwd=tree, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - start
    if done.returncode != 0:
        raise SystemExit(f"terra {' '.join(args)} from {tree}: exit {done.returncode}: {done.stderr.strip()[-400:]}")
    timed = subprocess.run(
        [sys.executable, "-X", "importtime", "-m", "terra", *args], cwd=tree, env=env, capture_output=True, text=True
    )
    return wall, import_seconds(timed.stderr)


def graph_digest(bundle: Path) -> str:
    """The scene graph's arrays and JSON, as the manifest's digests of component graph/."""
    manifest = json.loads((bundle / "manifest.json").read_text())
    files = manifest.get("files", {})
    return json.dumps({k: v for k, v in sorted(files.items()) if k.startswith("graph/")}, sort_keys=True)


def commands(bundle: Path, copy: Path, config: Path) -> dict[str, list[str]]:
    return {
        "--help": ["--help"],
        "info": ["info", str(bundle)],
        "find (cold)": ["find", str(bundle), "find the dumpster", "--json"],
        "build 1.0 m": ["build", str(copy), "--config", str(config), "--overwrite", "-q"],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--bundle", type=Path, required=True, help="a mapped campus bundle (terra map)")
    parser.add_argument("--baseline", default="cefcc6e", help="the commit to compare this checkout with")
    parser.add_argument("--runs", type=int, default=7)
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "startup.json")
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="terra-startup-"))
    config = work / "grid-1m.yaml"
    config.write_text("build:\n  grid:\n    cell_size: 1.0\n")
    trees = {"before": unpack(args.baseline, work), "after": ROOT}
    copies = {}
    for label in trees:
        copies[label] = work / f"{label}.terra"
        shutil.copytree(args.bundle, copies[label])
    samples: dict[str, dict[str, list[tuple[float, float]]]] = {label: {} for label in trees}
    for _ in range(args.runs):
        for label, tree in trees.items():
            for name, argv in commands(args.bundle, copies[label], config).items():
                samples[label].setdefault(name, []).append(run_once(tree, argv))
    same = graph_digest(copies["before"]) == graph_digest(copies["after"])
    result: dict = {
        "command": " ".join(sys.argv),
        "baseline": args.baseline,
        "bundle": str(args.bundle),
        "runs": args.runs,
        "cpus": os.cpu_count(),
        "load_average_1min_at_start": os.getloadavg()[0],
        "same_graph": same,
        "commands": {},
    }
    rows = []
    for name in samples["after"]:
        entry = {}
        for label in trees:
            walls = [w for w, _ in samples[label][name]]
            imports = [i for _, i in samples[label][name]]
            entry[label] = {
                "wall_median_s": round(statistics.median(walls), 3),
                "wall_min_s": round(min(walls), 3),
                "import_median_s": round(statistics.median(imports), 3),
            }
        result["commands"][name] = entry
        before, after = entry["before"], entry["after"]
        target = "<= 0.8 s" if name.startswith("build") else ""
        rows.append(
            (
                f"terra {name}",
                f"wall {before['wall_median_s']:.2f} -> {after['wall_median_s']:.2f} s, "
                f"imports {before['import_median_s']:.2f} -> {after['import_median_s']:.2f} s",
                target,
            )
        )
    rows.append(("same graph before and after", str(same), "True"))
    report(rows, result, args.out)
    shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
