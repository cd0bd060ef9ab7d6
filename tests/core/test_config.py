"""terra.config.TerraConfig: a command's YAML file read once, each stage handed its section, the
same one-line errors as before for a bad file or section."""

import pytest

import terra.fileio
from terra.config import TerraConfig, load_section
from terra.errors import TerraError


@pytest.fixture
def reads(monkeypatch) -> list:
    """The paths read_yaml is asked for from now on."""
    asked: list = []
    read_yaml = terra.fileio.read_yaml

    def counting(path, *args, **kwargs):
        asked.append(path)
        return read_yaml(path, *args, **kwargs)

    monkeypatch.setattr(terra.fileio, "read_yaml", counting)
    return asked


def test_sections_come_from_one_read(tmp_path, reads):
    path = tmp_path / "c.yaml"
    path.write_text(
        "mapping:\n  checkpoint_every: 7\ntasks:\n  retrieval:\n    default_alpha: 0.3\ndataset:\n  topic: /points\n"
    )
    config = TerraConfig.read(path)
    assert config.mapping.checkpoint_every == 7 and config.tasks.retrieval.default_alpha == 0.3
    assert config.build == load_section(None, "build") and config.dataset == {"topic": "/points"}
    assert len(reads) == 1


def test_the_demo_reads_its_file_once(tmp_path, reads):
    from terra.eval.demo import DemoConfig

    path = tmp_path / "c.yaml"
    path.write_text("tasks:\n  retrieval:\n    default_alpha: 0.3\n")
    demo = DemoConfig.load(path, "tiny", 0)
    assert len(reads) == 1
    assert (
        demo.tasks.retrieval.default_alpha == 0.3 and demo.mapping.perception.noise.miss_rate > 0
    )  # the demo's default noise
    path.write_text("mapping:\n  perception:\n    noise: none\n")
    assert DemoConfig.load(path, "tiny", 0).mapping.perception.noise.miss_rate == 0  # the file's own noise


def test_overrides_take_the_place_of_the_file(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("mapping:\n  checkpoint_every: 7\n  perception:\n    noise: realistic\n")
    config = TerraConfig.read(path, {"mapping": {"perception": {"noise": "none"}}})
    assert config.mapping.checkpoint_every == 7 and config.mapping.perception.noise.miss_rate == 0
    assert config.sets("mapping", "perception", "noise") and not config.sets("mapping", "fusion")


def test_errors_are_one_line_naming_the_file_stage_and_field(tmp_path):
    path = tmp_path / "c.yaml"
    path.write_text("mapping:\n  checkpoint_every: many\ntasks: 3\n")
    config = TerraConfig.read(path)
    with pytest.raises(TerraError, match=r"c.yaml \[mapping\]: field 'checkpoint_every': ") as exc:
        _ = config.mapping
    assert "\n" not in str(exc.value)
    with pytest.raises(TerraError, match="field 'tasks' must be a mapping of the tasks section's options"):
        _ = config.tasks
    assert config.build is not None  # a bad section a command does not use does not stop it
    path.write_text("mappin: {}\n")
    with pytest.raises(TerraError, match="unknown top-level key 'mappin'"):
        TerraConfig.read(path)
