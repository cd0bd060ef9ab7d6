"""Session fixtures shared by every area: the text embedder and the simulated campuses.

Expensive artefacts (simulated datasets, maps, graphs) are built once per test session; each
area's fixtures live beside its tests (tests/<area>/fixtures.py).
"""

import os

import pytest

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
os.environ.setdefault("TOKENIZERS_PARALLELISM", "false")

pytest_plugins = [
    "tests.mapping.fixtures",
    "tests.graph.fixtures",
    "tests.graph.fixtures_ground",
    "tests.eval.fixtures",
    "tests.perception.fixtures",
    "tests.interop.fixtures",
    "tests.datasets.fixtures_ros",
    "tests.reliability.fixtures",
]


@pytest.fixture(scope="session")
def text_embedder():
    from terra.perception.text import get_text_embedder

    return get_text_embedder()


@pytest.fixture(scope="session")
def tiny_campus():
    from terra.sim import simulate

    return simulate("tiny", seed=0)


@pytest.fixture(scope="session")
def small_campus():
    from terra.sim import simulate

    return simulate("small", seed=0)
