import pytest

from terra.cli import main
from terra.config import load_section
from terra.errors import TerraError


def run(args, capsys):
    with pytest.raises(SystemExit) as exc:
        main(args)
    out = capsys.readouterr()
    return exc.value.code, out.out, out.err


def test_config_dump_every_stage_round_trips(tmp_path, capsys):
    for stage in ["sim", "mapping", "build", "tasks", "eval"]:
        code, out, _ = run(["config", "dump", stage], capsys)
        assert code in (0, None)
        path = tmp_path / f"{stage}.yaml"
        path.write_text(out)
        assert load_section(path, stage) == load_section(None, stage)


def test_unknown_stage_is_exit_2_one_line(capsys):
    code, _, err = run(["config", "dump", "nope"], capsys)
    assert code == 2
    assert err.strip().count("\n") == 0 and "unknown stage 'nope'" in err


def test_bad_config_key_names_the_field(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("mapping:\n  no_such_field: 1\n")
    with pytest.raises(TerraError, match="no_such_field"):
        load_section(path, "mapping")
    path.write_text("bogus: {}\n")
    with pytest.raises(TerraError, match="unknown top-level key 'bogus'"):
        load_section(path, "mapping")
