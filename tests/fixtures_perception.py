"""Session fixtures of the perception stage: tiny randomly initialised models (tests/perception_models.py).

`tiny_clip_dir`: a CLIP model folder (32 x 32 images, 16-d embeddings) saved with save_pretrained.
"""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def tiny_clip_dir(tmp_path_factory):
    pytest.importorskip("transformers")
    from tests.perception_models import save_clip

    return save_clip(tmp_path_factory.mktemp("clip") / "tiny-clip")
