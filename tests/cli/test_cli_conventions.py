"""What every command does the same way: --version, help that reads as text, one rule for existing
outputs, one line on Ctrl-C with exit code 130, counts in the right number."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from terra import __version__
from terra.cli import run
from terra.words import counted
from tests.cli.signals import ctrl_c_default

REPO = Path(__file__).resolve().parents[2]


def call(argv, capsys):
    code = run(argv)
    out = capsys.readouterr()
    return code, out.out, out.err


def command_paths() -> list[list[str]]:
    import typer
    from typer.core import TyperGroup

    from terra.cli import _load_commands, app

    _load_commands()
    root = typer.main.get_command(app)
    assert isinstance(root, TyperGroup)
    paths = []
    for name, command in root.commands.items():
        subs = getattr(command, "commands", None)
        paths += [[name, sub] for sub in subs] if subs else [[name]]
    return paths


def test_version(capsys):
    code, out, _ = call(["--version"], capsys)
    assert code == 0 and out == f"terra {__version__}\n"


def test_the_command_list_has_one_whole_line_per_command(capsys):
    code, out, _ = call(["--help"], capsys)
    assert code == 0
    listed = out.split("Commands:\n")[1].strip().splitlines()
    names = {p[0] for p in command_paths()}
    assert {line.split()[0] for line in listed} == names  # no line is a docstring's continuation
    for line in listed:
        assert not line.rstrip().endswith("..."), line  # summaries fit, nothing cut off


@pytest.mark.parametrize("path", command_paths(), ids=lambda p: " ".join(p))
def test_help_has_plain_placeholders_and_an_example(path, capsys):
    code, out, _ = call(path + ["--help"], capsys)
    assert code == 0
    assert not re.search(r"<(bool|path|str|int|float|list)", out), out  # typer's type tags
    assert not re.search(r"\{[a-z_]+\}", out), out  # typer's {bundle} for a required argument
    usage = out.splitlines()[0]
    assert usage.startswith(f"Usage: terra {' '.join(path)} [OPTIONS]")
    assert usage == usage.replace(usage[len("Usage: terra ") :], usage[len("Usage: terra ") :])  # one line
    assert re.search(r"^\s*Examples?\b.*terra ", out, re.M), out  # an example to copy
    # The example lines are kept whole (not wrapped in the middle of a command).
    for line in out.splitlines():
        if line.strip().startswith("Example") and "terra " in line:
            assert line.count('"') % 2 == 0, line


def test_counts_take_the_right_number():
    assert counted(1, "region") == "1 region" and counted(0, "region") == "0 regions"
    assert counted(1, "query", "queries") == "1 query" and counted(3, "query", "queries") == "3 queries"
    assert counted(12_000, "point") == "12,000 points"


# ------------------------------------------------------------------ existing outputs


def test_map_refuses_an_existing_bundle_unless_overwrite(tmp_path, capsys):
    out = tmp_path / "campus.terra"
    out.mkdir()
    (out / "manifest.json").write_text("{}")
    code, _, err = call(["map", "--sim", "tiny", "--out", str(out), "-q"], capsys)
    assert code == 2 and err == f"terra: error: {out}: exists (pass --overwrite to replace it)\n"
    assert [p.name for p in out.iterdir()] == ["manifest.json"]


def test_eval_and_tune_refuse_existing_outputs_before_any_work(tmp_path, capsys):
    report = tmp_path / "report"
    report.mkdir()
    (report / "summary.json").write_text("{}")
    missing = tmp_path / "no-bundle.terra"
    code, _, err = call(["eval", str(missing), "--gt", str(tmp_path), "--out", str(report)], capsys)
    assert code == 2 and f"{report}: exists (pass --overwrite to replace it)" in err
    (report / "tuned.json").write_text("{}")
    code, _, err = call(["eval", str(missing), "--gt", str(tmp_path), "--tune", "--out", str(report)], capsys)
    assert code == 2 and f"{report / 'tuned.json'}: exists" in err
    # With --overwrite the command goes on to its inputs (here: the missing bundle).
    code, _, err = call(["eval", str(missing), "--gt", str(tmp_path), "--out", str(report), "--overwrite"], capsys)
    assert code == 2 and "exists" not in err and "no-bundle.terra" in err


def test_render_refuses_an_existing_picture_unless_overwrite(interop_bundle, tmp_path, capsys):
    out = tmp_path / "places.png"
    out.write_bytes(b"mine")
    code, _, err = call(["render", str(interop_bundle.path), "--what", "places", "--out", str(out)], capsys)
    assert code == 2 and "exists (pass --overwrite to replace it)" in err and out.read_bytes() == b"mine"
    argv = ["render", str(interop_bundle.path), "--what", "places", "--out", str(out), "--overwrite"]
    code, _, _ = call(argv, capsys)
    assert code == 0 and out.read_bytes()[:4] == b"\x89PNG"


def test_demo_refuses_a_folder_that_is_not_a_demo_folder(tmp_path, capsys):
    (tmp_path / "notes.txt").write_text("mine")
    code, _, err = call(["demo", "--out", str(tmp_path), "--preset", "tiny"], capsys)
    assert code == 2 and "not a terra demo folder" in err
    assert [p.name for p in tmp_path.iterdir()] == ["notes.txt"]


# ------------------------------------------------------------------ Ctrl-C


def test_interruption_message_says_what_was_kept():
    from terra.cli.interrupts import NOTHING_WRITTEN, clear, interrupted_message, on_interrupt

    clear()
    assert interrupted_message() == f"terra: interrupted; {NOTHING_WRITTEN}"
    on_interrupt(lambda: "the map up to frame 7 is checkpointed")
    assert interrupted_message() == "terra: interrupted; the map up to frame 7 is checkpointed"
    on_interrupt(lambda: str(1 / 0))  # a note that fails never hides the interruption
    assert interrupted_message() == f"terra: interrupted; {NOTHING_WRITTEN}"
    clear()


@pytest.mark.slow
def test_ctrl_c_during_map_prints_the_resume_line_and_exits_130(tmp_path):
    """A real SIGINT to `terra map` in its own process: one line naming the checkpoint, exit
    code 130, the checkpoint kept and no bundle written."""
    out = tmp_path / "campus.terra"
    config = tmp_path / "terra.yaml"
    config.write_text("mapping:\n  checkpoint_every: 1\n")
    env = {**os.environ, "TERRA_PROGRESS": "lines", "TERRA_PROGRESS_INTERVAL": "0", "PYTHONPATH": str(REPO)}
    argv = [sys.executable, "-m", "terra", "map", "--sim", "tiny", "--out", str(out), "--config", str(config)]
    proc = subprocess.Popen(
        argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=REPO, preexec_fn=ctrl_c_default
    )
    assert proc.stderr is not None
    seen = []
    for line in proc.stderr:
        seen.append(line)
        if re.match(r"terra: mapping 3/", line):
            proc.send_signal(signal.SIGINT)
            break
    rest = proc.stderr.read()
    proc.wait(timeout=120)
    last = (seen + rest.splitlines(keepends=True))[-1].strip()
    assert proc.returncode == 130, "".join(seen) + rest
    match = re.fullmatch(
        rf"terra: interrupted; the map up to frame (\d+) is checkpointed in "
        rf"{re.escape(str(out))}\.partial; run the same command again to resume",
        last,
    )
    assert match and int(match.group(1)) >= 3, last
    assert "Traceback" not in rest and not out.exists() and (tmp_path / "campus.terra.partial").is_dir()
    state = json.loads((tmp_path / "campus.terra.partial" / "state" / "state" / "meta.json").read_text())
    assert state["next_frame"] == int(match.group(1))
