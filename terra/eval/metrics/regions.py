"""Region monitoring metrics (the paper's Table III): precision, recall and F1 over place sets.

The ground-truth set of a named region is the places whose map-frame xy lies in its closed
polygon: the boundary counts, because the simulator's region polygons and the places derived from
its grid-aligned terrain often share coordinates, and a place on a region's edge belongs to it.
Scores are micro-averaged over queries: true positives, false positives and false negatives are
summed over all queries before the ratios are taken.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass

import numpy as np

from terra.eval.metrics.retrieval import f1_score
from terra.tasks.monitoring import places_in_polygon

__all__ = ["SetScores", "micro_scores", "places_in_polygon", "set_scores"]


@dataclass
class SetScores:
    """Counts and ratios of a predicted set against a true set (empty denominators give 0)."""

    tp: int
    fp: int
    fn: int

    @property
    def precision(self) -> float:
        return self.tp / (self.tp + self.fp) if self.tp + self.fp else 0.0

    @property
    def recall(self) -> float:
        return self.tp / (self.tp + self.fn) if self.tp + self.fn else 0.0

    @property
    def f1(self) -> float:
        return f1_score(self.precision, self.recall)

    def __add__(self, other: SetScores) -> SetScores:
        return SetScores(self.tp + other.tp, self.fp + other.fp, self.fn + other.fn)

    def to_json(self) -> dict:
        return {**asdict(self), "precision": self.precision, "recall": self.recall, "f1": self.f1}


def set_scores(predicted: Sequence[int] | np.ndarray, truth: Sequence[int] | np.ndarray) -> SetScores:
    """Compare two sets of place indices (duplicates ignored)."""
    p = np.unique(np.asarray(predicted, dtype=np.int64))
    g = np.unique(np.asarray(truth, dtype=np.int64))
    tp = int(np.intersect1d(p, g, assume_unique=True).size)
    return SetScores(tp=tp, fp=int(p.size - tp), fn=int(g.size - tp))


def micro_scores(per_query: Iterable[SetScores]) -> SetScores:
    """Sum of the counts of every query (micro average)."""
    total = SetScores(0, 0, 0)
    for s in per_query:
        total = total + s
    return total
