"""Ctrl-C gives one line saying what was kept and exit code 130 in every command, also when it lands
inside a compiled kernel (numba turns the KeyboardInterrupt into a SystemError) or a server loop."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest
import typer

from terra.cli.interrupts import Interrupted, catch_interrupts
from tests.cli.signals import ctrl_c_default

REPO = Path(__file__).resolve().parents[2]


def _command(body):
    app = typer.Typer()
    app.command()(body)
    return catch_interrupts(typer.main.get_command(app))


def test_an_interrupt_inside_a_compiled_kernel_is_an_interruption():
    def kernel_interrupted() -> None:
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt:
            raise SystemError("CPUDispatcher(<function cull_kernel>) returned a result with an exception set")  # noqa: B904

    with pytest.raises(Interrupted):
        _command(kernel_interrupted).main(args=[], standalone_mode=False)


def test_any_other_system_error_is_not_taken_for_an_interruption():
    def broken() -> None:
        raise SystemError("a real defect")

    with pytest.raises(SystemError, match="a real defect"):
        _command(broken).main(args=[], standalone_mode=False)


def test_ctrl_c_stops_the_service_with_one_line_and_130(tiny_graph_bundle):
    pytest.importorskip("uvicorn")
    from tests.serve.test_serve import free_port

    port = free_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "terra", "serve", str(tiny_graph_bundle.path), "--port", str(port)],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=ctrl_c_default,
    )
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            try:
                urllib.request.urlopen(f"http://127.0.0.1:{port}/health", timeout=1)
                break
            except OSError:
                assert proc.poll() is None, proc.communicate()
                time.sleep(0.3)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, err
    assert err.strip().splitlines()[-1] == (
        f"terra: interrupted; the service on port {port} stopped; {tiny_graph_bundle.path} is unchanged"
    )
