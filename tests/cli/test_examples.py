"""The files a newcomer copies: examples/ loads as the commands load it, and the README's first two
commands are what a fresh machine needs (CI runs the second one verbatim)."""

from __future__ import annotations

from pathlib import Path

import pytest

from terra.config import load_dataset_options, load_section, stage_names

REPO = Path(__file__).resolve().parents[2]
EXAMPLES = REPO / "examples"
CONFIGS = sorted(EXAMPLES.glob("*.yaml"))


def test_there_are_examples():
    assert {p.name for p in CONFIGS} >= {"campus.yaml", "models.yaml", "rosbag.yaml", "tasks.yaml"}


@pytest.mark.parametrize("path", [p for p in CONFIGS if p.name != "tasks.yaml"], ids=lambda p: p.name)
def test_example_configs_load_in_every_stage(path):
    for stage in stage_names():
        load_section(path, stage)  # TerraError (naming the key) for anything misspelt
    options = load_dataset_options(path)
    if options:  # a dataset section is validated by the loader it is for
        from terra.datasets.registry import LOADERS, loader_options

        loader_options(LOADERS.get("rosbag"), options, str(path))


def test_the_campus_example_sets_what_it_says():
    from terra.mapping.config import MappingConfig
    from terra.tasks.config import TasksConfig

    mapping = load_section(EXAMPLES / "campus.yaml", "mapping")
    assert isinstance(mapping, MappingConfig)
    assert mapping.perception.backend == "labels" and mapping.perception.noise.enabled
    tasks = load_section(EXAMPLES / "campus.yaml", "tasks")
    assert isinstance(tasks, TasksConfig) and tasks.planning.start_radius == 20.0
    models = load_section(EXAMPLES / "models.yaml", "mapping")
    assert isinstance(models, MappingConfig) and models.perception.backend == "models"


def test_the_example_task_file_drives_find_monitor_and_plan():
    from terra.tasks.task_file import load_task_file

    tasks = load_task_file(EXAMPLES / "tasks.yaml")
    assert tasks.object_queries() == ["Get bike from the bicycle rack", "Find the dumpster"]
    assert tasks.region_queries() == ["Large parking lot surrounded by buildings"]
    assert tasks.object_method("tasks.yaml") == ("3dsg", None) and tasks.region_method("tasks.yaml") is None
    assert tasks.unused_keys("find") == ["k", "region_tasks", "terrain_preferences", "queries"]
    assert tasks.unused_keys("monitor") == ["prediction_method", "object_tasks", "terrain_preferences", "queries"]
    assert tasks.unused_keys("plan") == ["k", "object_tasks", "region_tasks"]


def readme_commands() -> list[str]:
    text = (REPO / "README.md").read_text()
    block = text.split("```bash\n", 1)[1].split("```", 1)[0]
    return [line for line in block.splitlines() if line.strip()]


def test_readme_first_commands_install_then_demo_and_test():
    demo, tests = readme_commands()
    assert demo == 'pip install torch==2.13.0 -e ".[test]" && terra demo --out terra-demo'
    assert tests == (
        'pip install torch==2.13.0 -e ".[test]" && bash scripts/setup-test-browser.sh '
        "&& bash scripts/lint.sh && python -m pytest -q -p no:cacheprovider"
    )
    assert (REPO / "scripts" / "setup-test-browser.sh").is_file()


def test_ci_runs_the_readme_test_command_verbatim():
    _, tests = readme_commands()
    ci = (REPO / ".ci" / "run").read_text().splitlines()
    assert tests in ci


def test_readme_names_every_extra_of_the_package():
    import tomllib

    extras = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    readme = (REPO / "README.md").read_text()
    for name in extras:
        if name != "test":
            assert f"| `{name}` |" in readme, name


def walk_lines() -> list[str]:
    """The command walk (the bash block of the README's "Commands" section), comments removed."""
    text = (REPO / "README.md").read_text().split("## Commands\n", 1)[1]
    block = text.split("```bash\n", 1)[1].split("```", 1)[0]
    return [line.split("  #", 1)[0].rstrip() for line in block.splitlines() if line.strip()]


def walk_task_file(lines: list[str]) -> str:
    """The task file the walk writes with `cat > tasks.yaml <<'EOF'`."""
    first = lines.index("cat > tasks.yaml <<'EOF'")
    return "\n".join(lines[first + 1 : lines.index("EOF", first)]) + "\n"


def test_the_walk_reads_only_what_it_wrote(tmp_path):
    """From an empty folder: no file of the repository (examples/) is read, the task file is
    written before it is used, and `terra node ... O0` comes after a `terra find ... --save`."""
    lines = walk_lines()
    assert not any("examples/" in line for line in lines)
    written = lines.index("cat > tasks.yaml <<'EOF'")
    used = [i for i, line in enumerate(lines) if "--tasks tasks.yaml" in line]
    assert used and min(used) > written
    saved = [i for i, line in enumerate(lines) if line.startswith("terra find") and "--save" in line]
    objects = [i for i, line in enumerate(lines) if line.startswith("terra node") and " O" in line]
    assert objects and saved and min(saved) < min(objects)
    from terra.tasks.task_file import load_task_file

    path = tmp_path / "tasks.yaml"
    path.write_text(walk_task_file(lines))
    tasks = load_task_file(path)
    assert tasks.object_queries() == ["Find the dumpster"]
    assert tasks.region_queries() == ["Large parking lot surrounded by buildings"]


def test_the_walk_maps_with_the_demos_perception_noise():
    """`terra map` in the walk adds the noise the demo adds (so campus.terra is the demo's map), and
    monitors with the configured k, which the demo's tuning gives."""
    from terra.eval.demo import DemoConfig
    from terra.mapping.config import MappingConfig

    lines = walk_lines()
    maps = [line for line in lines if line.startswith("terra map")]
    assert len(maps) == 2 and all("--noise realistic" in line for line in maps)
    demo = DemoConfig.load(None, "small", 0).mapping.perception.noise
    walk = MappingConfig.model_validate({"perception": {"noise": "realistic"}}).perception.noise
    assert demo == walk and demo.enabled
    assert not any(line.startswith("terra monitor") and "--k" in line for line in lines)
