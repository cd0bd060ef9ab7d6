"""`terra serve` throughput: requests per second and latency percentiles for POST /find on a campus
bundle with N concurrent clients (default 8), each sending its requests back to back.

Starts `python -m terra serve BUNDLE` on a free loopback port (this checkout), waits for /health,
runs a warm-up, then `--requests` requests per client, and stops the server. The query texts rotate
over a few phrasings, so after the first round they come from the embedding cache, as a robot
repeating its questions would see.

Usage: python benchmarks/bench_serve.py --bundle /work/bench-cache/issue-15/campus.terra [--clients 8] [--requests 50]
Writes benchmarks/results/serve.json and prints a table. Run from the repository root.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import socket
import statistics
import subprocess
import sys
import time
import urllib.request
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from benchtable import report

QUERIES = ["find the dumpster", "where is the bicycle rack", "a bench to sit on", "the fire hydrant"]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def post(url: str, body: dict) -> tuple[int, float]:
    data = json.dumps(body).encode()
    t0 = time.perf_counter()
    request = urllib.request.Request(url, data=data, method="POST", headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(request, timeout=120) as response:
        response.read()
        return response.status, time.perf_counter() - t0


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(round(q / 100 * (len(ordered) - 1))))]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--bundle", type=Path, required=True)
    parser.add_argument("--clients", type=int, default=8)
    parser.add_argument("--requests", type=int, default=50, help="requests per client")
    parser.add_argument("--method", default="ms-avg")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results" / "serve.json")
    args = parser.parse_args()

    load_at_start = os.getloadavg()[0]
    port = free_port()
    root = Path(__file__).resolve().parents[1]
    t0 = time.perf_counter()
    server = subprocess.Popen(
        [sys.executable, "-m", "terra", "serve", str(args.bundle), "--port", str(port)],
        cwd=root,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    base = f"http://127.0.0.1:{port}"
    try:
        while True:
            try:
                with urllib.request.urlopen(base + "/health", timeout=5) as r:
                    if r.status == 200:
                        break
            except OSError as error:
                if server.poll() is not None:
                    stderr = server.stderr.read() if server.stderr is not None else ""
                    raise SystemExit(f"terra serve failed: {stderr}") from error
                time.sleep(0.2)
        startup_s = time.perf_counter() - t0
        url = base + "/find"
        for q in QUERIES:  # warm-up: every text embedded once
            post(url, {"queries": [q], "method": args.method})

        def client(c: int) -> list[float]:
            return [
                post(url, {"queries": [QUERIES[(c + i) % len(QUERIES)]], "method": args.method})[1]
                for i in range(args.requests)
            ]

        t0 = time.perf_counter()
        with ThreadPoolExecutor(args.clients) as pool:
            latencies = [t for per_client in pool.map(client, range(args.clients)) for t in per_client]
        elapsed = time.perf_counter() - t0
        single = [post(url, {"queries": [QUERIES[i % len(QUERIES)]], "method": args.method})[1] for i in range(20)]
    finally:
        server.terminate()
        server.wait(30)
    total = len(latencies)
    result = {
        "machine": platform.processor() or platform.machine(),
        "python": platform.python_version(),
        "cpus": os.cpu_count(),
        "load_average_1min_at_start": load_at_start,
        "bundle": str(args.bundle),
        "clients": args.clients,
        "requests": total,
        "method": args.method,
        "startup_s": startup_s,
        "elapsed_s": elapsed,
        "throughput_rps": total / elapsed,
        "p50_ms": 1e3 * percentile(latencies, 50),
        "p99_ms": 1e3 * percentile(latencies, 99),
        "max_ms": 1e3 * max(latencies),
        "single_client_median_ms": 1e3 * statistics.median(single),
    }
    rows = [
        ("server start to first /health (load bundle, text model)", f"{startup_s:.2f} s", "-"),
        (
            f"POST /find ({args.method}), {args.clients} concurrent clients, {total} requests",
            f"{result['throughput_rps']:.1f} requests/s",
            "-",
        ),
        (
            "latency p50 / p99 / max",
            f"{result['p50_ms']:.1f} / {result['p99_ms']:.1f} / {result['max_ms']:.1f} ms",
            "-",
        ),
        ("latency, one client at a time (median)", f"{result['single_client_median_ms']:.1f} ms", "-"),
    ]
    report(rows, result, args.out)


if __name__ == "__main__":
    main()
