"""Configuration of evaluation (`terra eval`): which metrics, on what, with which parameters.

Thresholds (alpha) and k are not set here: they come from a tuned file written by
`terra eval --tune` on a validation scene, or else from the tasks stage's defaults.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator

from terra.schemas import Section
from terra.tasks.config import RETRIEVAL_METHODS, RetrievalMethod


class SegmentationEval(Section):
    """Table I: the map's terrain segmenter on labelled images of the dataset.

    max_images: images evaluated, evenly spaced over the dataset (0 = skip the table).
    """

    max_images: int = Field(default=40, ge=0)


class RetrievalEval(Section):
    """Table II. Queries are `template` with {object} replaced by each class name; `classes`
    None means every class with an object in the ground truth, minus `exclude`."""

    methods: list[RetrievalMethod] = Field(default_factory=lambda: list(RETRIEVAL_METHODS))
    template: str = "Find the {object}"
    classes: list[str] | None = None
    exclude: list[str] = Field(default_factory=lambda: ["building", "tree", "crosswalk", "misc"])
    precision_ratio: float = Field(default=0.9, gt=0.0, le=1.0)

    @field_validator("template")
    @classmethod
    def _has_object(cls, v: str) -> str:
        if "{object}" not in v:
            raise ValueError("template must contain {object}")
        return v


class RegionsEval(Section):
    """Table III: monitoring the named regions with their descriptions as queries.

    methods: 'spectral' and 'agglomerative' are Terra's region hierarchies (built on the bundle's
    places with that method, timed) queried with `monitor_method`; 'aib' is Clio's information
    bottleneck on the places layer.
    """

    methods: list[Literal["spectral", "agglomerative", "aib"]] = Field(
        default_factory=lambda: ["aib", "spectral", "agglomerative"]
    )
    monitor_method: Literal["mix", "max", "thresh"] = "mix"


class NavigationEval(Section):
    """A plan from the place nearest the first camera pose to the place of the best object for
    `task`, without and with preferring the `prefer` terrains."""

    task: str = "Get bike from the bicycle rack"
    prefer: list[str] = Field(default_factory=lambda: ["sidewalk"])
    step: float = Field(default=0.1, gt=0.0, description="metres; path pieces read against the ground-truth terrain")
    route_pairs: int = Field(
        default=200,
        ge=0,
        description=(
            "place pairs joined by a route on the first preferred terrain, planned both ways (drawn with a fixed seed)"
        ),
    )
    min_share: float = Field(
        default=0.8,
        ge=0.0,
        le=1.0,
        description="a preferred plan should keep at least this share of its length on the preferred terrain",
    )


class TuneEval(Section):
    """Grids searched by `terra eval --tune` on a validation scene (never the test scene)."""

    alpha_min: float = 0.15
    alpha_max: float = 0.75
    alpha_steps: int = Field(default=13, ge=1)
    k_max: int = Field(default=8, ge=1)


class EvalConfig(Section):
    segmentation: SegmentationEval = Field(default_factory=SegmentationEval)
    retrieval: RetrievalEval = Field(default_factory=RetrievalEval)
    regions: RegionsEval = Field(default_factory=RegionsEval)
    navigation: NavigationEval = Field(default_factory=NavigationEval)
    tune: TuneEval = Field(default_factory=TuneEval)
    map_cell: float = Field(default=0.4, gt=0.0, description="metres; cell of the mapped-area count")
    figures: bool = True
    dpi: int = Field(default=110, ge=50, le=600)
