"""terra.background: a call on a second thread, its value or its exception taken later."""

from __future__ import annotations

import threading

import pytest

from terra.background import Background, usable_cores


def test_the_call_runs_at_once_beside_the_caller_and_gives_its_value():
    started, release = threading.Event(), threading.Event()

    def work(a: int, b: int) -> int:
        started.set()
        assert release.wait(10)
        return a * b

    job = Background(work, 6, 7, name="test-job")
    assert started.wait(10)  # running before result() is asked for
    assert job._thread.daemon and job._thread.name == "test-job"
    release.set()
    assert job.result() == 42
    assert job.result() == 42  # asked again: the same value


def test_the_calls_exception_is_raised_by_result():
    def fail() -> None:
        raise ValueError("the field 'x' is missing")

    job = Background(fail)
    with pytest.raises(ValueError, match="the field 'x' is missing"):
        job.result()


def test_usable_cores_counts_at_least_one():
    assert usable_cores() >= 1
