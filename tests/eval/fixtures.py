"""Session fixture of the evaluation area (see tests/conftest.py).

`tiny_demo`: `terra demo --preset tiny` run once per session, in-process, into a temporary
folder: the simulated tiny campus (seed 0) and its validation scene (seed 1), both bundles with
scene graphs, the tuned parameters, the report and demo.json, with what the command printed.
"""

from __future__ import annotations

import contextlib
import io
from dataclasses import dataclass
from pathlib import Path

import pytest


@dataclass
class DemoOutput:
    out: Path
    exit_code: int
    stdout: str
    stderr: str

    @property
    def dataset(self) -> Path:
        return self.out / "tiny-seed0" / "dataset"

    @property
    def bundle(self) -> Path:
        return self.out / "tiny-seed0" / "map.terra"

    @property
    def validation(self) -> Path:
        return self.out / "validation-tiny-seed1"


def run_cli(argv: list[str]) -> tuple[int, str, str]:
    """`terra ARGV` in-process: exit code, stdout, stderr."""
    from terra.cli import run

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = run(argv)
    return code, out.getvalue(), err.getvalue()


@pytest.fixture(scope="session")
def tiny_demo(tmp_path_factory, text_embedder) -> DemoOutput:
    out = tmp_path_factory.mktemp("demo") / "terra-demo"
    code, stdout, stderr = run_cli(["demo", "--out", str(out), "--preset", "tiny", "--seed", "0"])
    return DemoOutput(out, code, stdout, stderr)
