"""Fuzzing every reader through the command line (tests/reliability/fuzzing.py): mutated bundle manifests,
bundle arrays, scene graphs and map metadata; both dataset layouts and KITTI raw; ROS 1 and ROS 2
bags; config, task and msmap files; the authors' reference files (as bytes, as values: integers past
64 bits, non-finite ranges, odd dtypes and shapes; and renamed with numbers that are not numbers);
and issue 24's value families (node ids, coordinates, queries, tf quaternions, oversized images,
truncated bags, calibration values, HTTP requests: tests/reliability/families.py). Each input must
give exit 0 with a valid result or exit 2 with one line (HTTP: 2xx, or 4xx with a one-line JSON
error): never another exit
code, a traceback, a hang, a changed input bundle, or a file written outside the output path.

Hypothesis draws the mutations (derandomised: the same examples on every run) within a fixed
budget per reader, so the suite's time stays bounded; benchmarks/fuzz_readers.py runs the same
harness on >= 10,000 inputs. A second test runs the readers that once crashed the interpreter
(bundle arrays: a segmentation fault in SciPy; bags) in worker processes, where a crash or a hang
can be observed instead of taking the test run down.
"""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st

from tests.reliability.fuzzing import FAILURES, run_case, supervise, targets

# Examples per reader (about 0.03 to 0.3 s each in process).
BUDGET = {
    "bundle manifest": 25,
    "bundle arrays": 40,
    "scene graph": 25,
    "map metadata": 10,
    "dataset terra-folder": 15,
    "dataset semantickitti": 15,
    "dataset kitti-raw": 15,
    "bag rosbag1": 12,
    "bag rosbag2": 12,
    "config file": 20,
    "task file": 20,
    "msmap yaml": 15,
    "reference files": 20,
    "reference values": 40,
    "reference names": 12,
    # Issue 24's value families (tests/reliability/families.py): a few cases each, many in the benchmark.
    "ids: node": 8,
    "coordinates": 8,
    "queries": 5,
    "tf quaternions": 6,
    "images: folder": 4,
    "images: bag": 4,
    "truncated: rosbag1": 8,
    "truncated: rosbag2": 8,
    "calibration: kitti-raw": 5,
    "calibration: semantickitti": 5,
    "calibration: terra-folder": 5,
    "http": 8,
}
FUZZ = settings(
    deadline=None,
    derandomize=True,
    database=None,
    phases=[Phase.explicit, Phase.generate],
    # Every current health check (iterating HealthCheck leaves the deprecated ones out); the isinstance
    # filter keeps them all and tells the type checker what hypothesis's untyped metaclass yields.
    suppress_health_check=[check for check in HealthCheck if isinstance(check, HealthCheck)],
)


def test_every_reader_has_a_budget(reliability_seeds):
    assert set(BUDGET) == set(targets(reliability_seeds))


@pytest.mark.parametrize("name", list(BUDGET))
def test_mutated_inputs_give_a_valid_result_or_one_line(reliability_seeds, tmp_path_factory, name):
    target = targets(reliability_seeds)[name]
    work = tmp_path_factory.mktemp("fuzz")
    seen: dict[str, int] = {}

    @settings(FUZZ, max_examples=BUDGET[name])
    @given(rng=st.randoms(use_true_random=False))
    def check(rng):
        result = run_case(target, reliability_seeds, rng, work, timeout=60.0)
        seen[result["outcome"]] = seen.get(result["outcome"], 0) + 1
        assert result["outcome"] not in FAILURES, result

    check()
    assert seen.get("refused", 0) > 0, f"no mutation of {name} was refused: the mutations miss the reader ({seen})"


@pytest.mark.slow
def test_no_mutated_input_crashes_or_hangs_a_process(reliability_seeds, tmp_path):
    """Worker processes (each running many inputs) observed from outside: zero crashes, zero hangs."""
    jobs = [
        {"target": name, "seed": seed, "seeds": reliability_seeds.to_json(), "work": str(tmp_path)}
        for name in ("bundle arrays", "bag rosbag1", "bag rosbag2")
        for seed in range(20)
    ]
    results = supervise(jobs, workers=2, timeout=120.0)
    assert len(results) == len(jobs)
    failed = [r for r in results if r["outcome"] in FAILURES]
    assert not failed, failed[:3]
