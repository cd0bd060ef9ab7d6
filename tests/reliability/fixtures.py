"""Session fixtures of the reliability tests (hardened inputs, crash-safe outputs).

`reliability_seeds`: a 3-frame simulated campus in every dataset format, its bundle with a scene
graph, the authors' reference files of it, and config, task and msmap files (tests.reliability.fuzzing.Seeds).
Tests copy what they mutate; the seeds themselves are never changed.
"""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def reliability_seeds(tmp_path_factory):
    from tests.reliability.fuzzing import build_seeds

    return build_seeds(tmp_path_factory.mktemp("reliability-seeds"))
