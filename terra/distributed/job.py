"""A distributed perception job: everything a worker needs to perceive any frame of a run, as JSON.

The client sends the job's text with every task (a few kilobytes), so a worker that joins late or is
restarted after a crash needs nothing else. `expect` holds what the client saw, and a worker refuses
to work when its own view differs: another Terra version, another dataset at that path, another frame
count or class table, or another perception backend key (other model files or settings), since its
cache entries would then never be read by the client.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import terra
from terra.bundle import dumps_json
from terra.datasets.base import Dataset
from terra.distributed.source import SourceSpec
from terra.mapping.checkpoint import fingerprint
from terra.mapping.config import MappingConfig
from terra.perception.cache import CachedPerception


@dataclass(frozen=True)
class PerceptionJob:
    """source: how to open the frames. config: the mapping config (JSON) whose `perception` section and
    image checks apply. cache_root: absolute cache folder shared by the client and the workers.
    expect: {"terra" (version), "dataset", "frames", "classes" (fingerprint of the class table), "backend"
    (backend key)}."""

    source: SourceSpec
    config: dict[str, Any]
    cache_root: str
    expect: dict[str, Any]

    @classmethod
    def for_run(
        cls, source: SourceSpec, dataset: Dataset, config: MappingConfig, perception: CachedPerception
    ) -> PerceptionJob:
        """The job of mapping `dataset` (opened from `source`) with `perception` (already cached)."""
        return cls(
            source,
            config.model_dump(mode="json"),
            str(perception.cache.root.absolute()),
            {
                "terra": terra.__version__,
                "dataset": dataset.name,
                "frames": len(dataset),
                "classes": classes_fingerprint(dataset),
                "backend": perception.cache.backend_key,
            },
        )

    def to_text(self) -> str:
        fields = {"source": self.source.to_json(), "config": self.config, "cache_root": self.cache_root}
        return dumps_json({**fields, "expect": self.expect})

    @classmethod
    def from_text(cls, text: str) -> PerceptionJob:
        data = json.loads(text)
        return cls(SourceSpec.from_json(data["source"]), data["config"], data["cache_root"], data["expect"])

    @cached_property
    def key(self) -> str:
        """SHA-256 of the job's text: Dask task keys of this job start with its first 16 hex."""
        return fingerprint(json.loads(self.to_text()))

    def task_key(self, index: int) -> str:
        return f"terra-perceive-{self.key[:16]}-{int(index)}"

    def mapping_config(self) -> MappingConfig:
        return MappingConfig.model_validate(self.config)


def classes_fingerprint(dataset: Dataset) -> str:
    return fingerprint(dataset.classes.to_json())
