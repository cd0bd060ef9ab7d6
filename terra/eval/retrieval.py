"""Table II: open-set object retrieval on Terra's map and graph against the simulator's objects.

One query per evaluated class, "Find the {object}", all queries in one `find_objects` call (each
query is a distractor for the others, as in the authors' evaluation). Ground truth for a query is
every object of that class.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from terra.datasets.ground_truth import GroundTruth
from terra.eval.config import RetrievalEval
from terra.eval.metrics.boxes import BoxSet
from terra.eval.metrics.retrieval import RetrievalScores, evaluate_retrieval
from terra.graph.scene_graph import SceneGraph
from terra.mapping.semantic_map import MetricSemanticMap
from terra.perception.text import TextEmbedder


@dataclass
class RetrievalTask:
    """The evaluated classes, their query texts, and each query's ground-truth boxes."""

    classes: list[str]
    queries: list[str]
    gt: list[BoxSet]

    @property
    def num_gt(self) -> int:
        return sum(len(b) for b in self.gt)

    def gt_boxes(self) -> tuple[BoxSet, np.ndarray]:
        """All ground-truth boxes and the query index of each."""
        boxes = [b for b in self.gt if len(b)]
        if not boxes:
            return BoxSet.empty(), np.zeros(0, dtype=np.int64)
        query = np.concatenate([np.full(len(b), q) for q, b in enumerate(self.gt)])
        return BoxSet(
            np.vstack([b.center for b in boxes]),
            np.vstack([b.size for b in boxes]),
            np.concatenate([b.yaw for b in boxes]),
        ), query


def retrieval_task(gt: GroundTruth, config: RetrievalEval) -> RetrievalTask:
    """Classes to query (configured, or every object class present minus the excluded ones, by
    name order) with their queries and ground truth."""
    present = sorted({o.class_name for o in gt.objects})
    classes = list(config.classes) if config.classes is not None else [c for c in present if c not in config.exclude]
    queries = [config.template.format(object=c) for c in classes]
    boxes = [BoxSet.from_objects([o for o in gt.objects if o.class_name == c]) for c in classes]
    return RetrievalTask(classes, queries, boxes)


@dataclass
class RetrievalRun:
    """Predictions of one method: boxes, (n, Q) scores, (n,) query index, wall seconds."""

    boxes: BoxSet
    scores: np.ndarray
    query: np.ndarray
    seconds: float

    def evaluate(self, task: RetrievalTask, precision_ratio: float = 0.9) -> RetrievalScores:
        return evaluate_retrieval(self.boxes, self.scores, self.query, task.gt, precision_ratio, task.queries)


def run_retrieval(
    msm: MetricSemanticMap,
    graph: SceneGraph | None,
    queries: list[str],
    method: str,
    alpha: float | None,
    embedder: TextEmbedder,
    tasks_config=None,
) -> RetrievalRun:
    """Run `find_objects` once for all queries and collect its boxes."""
    from terra.tasks.retrieval import find_objects

    start = time.perf_counter()
    found = find_objects(msm, graph, queries, method=method, alpha=alpha, config=tasks_config, embedder=embedder)
    seconds = time.perf_counter() - start
    boxes = BoxSet.from_objects(found)
    scores = np.array([o.scores for o in found], dtype=np.float64).reshape(len(found), len(queries))
    return RetrievalRun(boxes, scores, np.array([o.query for o in found], dtype=np.int64), seconds)
