"""The error line is the only output of a refused command, and it is short and printable.

- A library's warning met on the way to a refusal (torch's "Detected pickle protocol 4" before its
  weights-only loader refuses such a file) is not printed: stderr is the one line.
  The same warning on a command that succeeds is still shown (it may matter to the user).
- An input of 10,000 characters echoed by an error is cut to its start and its length (the count
  checked against len() of the input), in the CLI's line and in the service's JSON error.
- Control characters in an echoed input are shown escaped: the line stays one line.
- A path longer than the system allows is one line (it was an OSError traceback).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from terra.errors import MAX_ECHO, MAX_LINE, TerraError, one_line, shorten
from tests.reliability.fuzzing import cli

REPO = Path(__file__).resolve().parents[2]
CLASSES = "sidewalk,grass,asphalt,dirt,water"


def terra(*args) -> subprocess.CompletedProcess:
    """A real `terra` process: pytest records warnings of in-process runs itself, hiding the noise."""
    env = {**os.environ, "HF_HUB_OFFLINE": "1", "TRANSFORMERS_OFFLINE": "1"}
    return subprocess.run(
        [sys.executable, "-m", "terra", *map(str, args)], cwd=REPO, capture_output=True, text=True, env=env, timeout=300
    )


def _reference_with(seeds, tmp_path: Path, protocol: int) -> Path:
    """The authors' files with the image embeddings saved under pickle `protocol` (torch's own is 2)."""
    import torch

    folder = Path(shutil.copytree(seeds.reference, tmp_path / "reference"))
    images = torch.load(folder / "clip_imgs_itr2.pt", weights_only=True)
    torch.save(images, folder / "clip_imgs_itr2.pt", pickle_protocol=protocol)
    return folder


def _lines(stderr: str) -> list[str]:
    # "still working" heartbeats are progress on a slow step, not noise of the refusal
    return [line for line in stderr.splitlines() if line.strip() and "still working" not in line]


def test_a_refusal_after_a_library_warning_prints_only_its_line(reliability_seeds, tmp_path):
    folder = _reference_with(reliability_seeds, tmp_path, 4)  # torch's weights-only loader refuses protocol 4
    done = terra("import", folder, "-f", "terra-reference", "-o", tmp_path / "x.terra", "--terrain-classes", CLASSES)
    assert done.returncode == 2, done.stderr
    assert _lines(done.stderr) == [
        f"terra: error: {folder / 'clip_imgs_itr2.pt'}: holds data other than tensors; "
        "only tensors are read from the reference's torch files"
    ]
    assert not (tmp_path / "x.terra").exists()


def test_a_warning_of_a_command_that_succeeds_is_still_shown(reliability_seeds, tmp_path):
    folder = _reference_with(reliability_seeds, tmp_path, 3)  # read, with torch's warning
    done = terra("import", folder, "-f", "terra-reference", "-o", tmp_path / "x.terra", "--terrain-classes", CLASSES)
    assert done.returncode == 0, done.stderr
    assert done.stderr.count("Detected pickle protocol 3") == 1, done.stderr


def test_shorten_keeps_the_start_and_says_the_length():
    text = "7" * 10_000
    short = shorten(text)
    assert short == "7" * (MAX_ECHO - 3) + "... (10,000 characters)"
    assert one_line(short) == short and shorten("x" * MAX_ECHO) == "x" * MAX_ECHO


@pytest.mark.parametrize(
    "message,kept",
    [
        ("node '" + "9" * 10_000 + "': expected a short name", "' (10,000 characters): expected a short name"),
        ('query "' + "a b " * 2500 + '" matched nothing', '..." (10,000 characters) matched nothing'),
        ("/data/" + "x" * 9_994 + ": no such file", "... (10,000 characters): no such file"),
    ],
)
def test_every_terra_error_caps_what_it_echoes(message, kept):
    line = str(TerraError(message))
    assert len(line) < 2 * MAX_ECHO and line.endswith(kept), line
    assert one_line(line) == line  # capping twice changes nothing (errors re-raised across processes)


def test_a_message_of_many_short_words_is_capped_as_a_whole():
    message = "classes: " + ", ".join(f"c{i}" for i in range(5_000))
    line = str(TerraError(message))
    assert line == message[: MAX_LINE - 3] + f"... ({len(message):,} characters)"


def test_control_characters_in_an_echoed_input_are_escaped():
    assert str(TerraError("query 'a\nb\x1b[2J\ud800 é ²' matched nothing")) == (
        "query 'a\\nb\\x1b[2J\\ud800 é ²' matched nothing"
    )


def test_a_10000_character_option_value_is_one_short_line(reliability_seeds):
    value = "x" * 10_000
    code, _, err = cli(["find", reliability_seeds.bundle, "dumpster", "--method", value])
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and len(lines[0]) < 3 * MAX_ECHO, err[:500]
    assert "x" * (MAX_ECHO - 5) + "...' (10,000 characters)" in lines[0]


def test_a_newline_in_an_option_value_stays_on_one_line(reliability_seeds):
    code, _, err = cli(["find", reliability_seeds.bundle, "dumpster", "--method", "ms_avg\nterra: error: fake"])
    assert code == 2 and len(err.strip().splitlines()) == 1 and "ms_avg\\nterra: error: fake" in err, err


def test_a_path_too_long_for_the_system_is_one_line(tmp_path):
    long_name = tmp_path / ("x" * 10_000)
    code, _, err = cli(["info", long_name])
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and "file name too long" in lines[0] and "(10," in lines[0], err[:500]


def test_the_service_caps_an_echoed_input(reliability_seeds):
    from fastapi.testclient import TestClient

    from terra.loaded import LoadedBundle
    from terra.serve.app import create_app
    from terra.serve.config import ServeConfig

    client = TestClient(create_app(LoadedBundle(reliability_seeds.bundle), settings=ServeConfig()))
    response = client.post("/plan", json={"to": "dumpster", "from": "y" * 1_000})  # the longest text allowed
    assert 400 <= response.status_code < 500
    error = response.json()["error"]
    assert len(error) < 3 * MAX_ECHO and "y" * (MAX_ECHO - 5) + "...' (1,000 characters)" in error, error[:500]


def test_a_usage_error_is_one_line_naming_the_help(reliability_seeds):
    code, _, err = cli(["node", reliability_seeds.bundle, "--at", "١٢", "3"])
    assert code == 2 and err.strip().splitlines() == [
        "terra: error: Invalid value for '--at': Input should be a valid number, unable to parse string as a "
        "number (see terra node -h)"
    ], err


def test_terra_alone_still_shows_its_help():
    code, out, err = cli([])
    assert "Usage: terra [OPTIONS] COMMAND" in out + err and "Commands:" in out + err
