"""Open-set object retrieval metrics (the paper's Table II), with Clio's definitions as the
authors' evaluation implements them.

For each query t with N_t ground-truth boxes:

- Matching: a greedy one-to-one assignment of predictions to ground truth by decreasing 3D IoU,
  pairs with IoU = 0 never match. A matched pair is a *relaxed* success when the predicted box
  contains the ground-truth centre, a *strict* success when, in addition, the ground-truth box
  contains the predicted centre.
- Accuracy: the N_t predictions with the highest score for t (whichever query they were
  assigned to) are matched to t's ground truth. IoU, SAcc and RAcc are the sums of matched IoU,
  strict and relaxed successes over all queries, each divided by sum_t N_t.
- Precision: the predictions assigned to t whose score is at least `precision_ratio` (0.9) times
  the best score among them are matched to t's ground truth. SPrec and RPrec are the strict and
  relaxed successes over all queries divided by the number of such predictions.
- F1 = 2 RPrec RAcc / (RPrec + RAcc) (0 when both are 0).
- Matched IoU: the mean IoU of the accuracy matches themselves (IoU divides by sum_t N_t, so a
  missed object counts as 0 there; here only the boxes that were matched count).
- By distance from the robot's path: the accuracy matches of the ground-truth objects whose centre
  lies in each distance band from the path (a polyline, metres, 2-D), so partial views from far
  away show apart from close ones.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from terra.eval.metrics.boxes import BoxSet, iou_matrix


def greedy_match(iou: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One-to-one matches (pred indices, gt indices) by decreasing IoU; only IoU > 0 matches.

    Ties are broken by (pred, gt) index order, so the result is deterministic.
    """
    iou = np.asarray(iou, dtype=np.float64)
    rows, cols = np.nonzero(iou > 0)
    order = np.lexsort((cols, rows, -iou[rows, cols]))
    used_p: set[int] = set()
    used_g: set[int] = set()
    matched_p, matched_g = [], []
    # Few boxes per query: a loop over candidate pairs is cheap and reads plainly.
    for p, g in zip(rows[order].tolist(), cols[order].tolist()):
        if p in used_p or g in used_g:
            continue
        used_p.add(p)
        used_g.add(g)
        matched_p.append(p)
        matched_g.append(g)
    return np.asarray(matched_p, dtype=np.int64), np.asarray(matched_g, dtype=np.int64)


@dataclass
class MatchCounts:
    """Matched pairs between a selection of predictions and a query's ground truth."""

    iou_sum: float = 0.0
    strict: int = 0
    relaxed: int = 0
    matches: int = 0

    def __iadd__(self, other: MatchCounts) -> MatchCounts:
        self.iou_sum += other.iou_sum
        self.strict += other.strict
        self.relaxed += other.relaxed
        self.matches += other.matches
        return self


def match_boxes(pred: BoxSet, gt: BoxSet) -> MatchCounts:
    """Greedy IoU matching of `pred` to `gt`, counting relaxed and strict successes."""
    iou = iou_matrix(pred, gt)
    p, g = greedy_match(iou)
    if p.size == 0:
        return MatchCounts()
    pred_has_gt_centre = pred.contains(gt.center)[p, g]
    gt_has_pred_centre = gt.contains(pred.center)[g, p]
    return MatchCounts(
        iou_sum=float(iou[p, g].sum()),
        strict=int(np.count_nonzero(pred_has_gt_centre & gt_has_pred_centre)),
        relaxed=int(np.count_nonzero(pred_has_gt_centre)),
        matches=int(p.size),
    )


@dataclass
class RetrievalScores:
    """Table II figures for one method. `per_query` holds the same counts for each query."""

    iou: float
    strict_accuracy: float
    relaxed_accuracy: float
    strict_precision: float
    relaxed_precision: float
    f1: float
    num_gt: int
    num_predictions: int
    num_precision_predictions: int
    per_query: list[dict] = field(default_factory=list)
    matched_iou: float = 0.0
    matches: int = 0

    def to_json(self) -> dict:
        return asdict(self)


def f1_score(precision: float, recall: float) -> float:
    """Harmonic mean of precision and recall (0 when both are 0)."""
    return 2 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0


def evaluate_retrieval(
    pred: BoxSet,
    scores: np.ndarray,
    assigned: np.ndarray,
    gt: list[BoxSet],
    precision_ratio: float = 0.9,
    query_names: list[str] | None = None,
) -> RetrievalScores:
    """Retrieval metrics of predicted boxes against the ground truth of Q queries.

    pred: the n predicted boxes. scores: (n, Q) score of each prediction for each query.
    assigned: (n,) query index each prediction was retrieved for. gt: per query, its boxes.
    """
    scores = np.asarray(scores, dtype=np.float64).reshape(len(pred), len(gt))
    assigned = np.asarray(assigned, dtype=np.int64).reshape(len(pred))
    total_acc, total_prec = MatchCounts(), MatchCounts()
    num_gt = num_sel = 0
    per_query = []
    for t, gt_t in enumerate(gt):
        acc, prec, mine = _query_matches(pred, scores[:, t], assigned, t, gt_t, precision_ratio)
        total_acc += acc
        total_prec += prec
        num_gt += len(gt_t)
        num_sel += int(mine.size)
        per_query.append(
            {
                "query": query_names[t] if query_names else str(t),
                "num_gt": len(gt_t),
                "num_predictions": int(np.count_nonzero(assigned == t)),
                "iou_sum": acc.iou_sum,
                "matches": acc.matches,
                "strict_hits": acc.strict,
                "relaxed_hits": acc.relaxed,
                "precision_predictions": int(mine.size),
                "strict_precision_hits": prec.strict,
                "relaxed_precision_hits": prec.relaxed,
            }
        )
    racc = total_acc.relaxed / num_gt if num_gt else 0.0
    rprec = total_prec.relaxed / num_sel if num_sel else 0.0
    return RetrievalScores(
        iou=total_acc.iou_sum / num_gt if num_gt else 0.0,
        strict_accuracy=total_acc.strict / num_gt if num_gt else 0.0,
        relaxed_accuracy=racc,
        strict_precision=total_prec.strict / num_sel if num_sel else 0.0,
        relaxed_precision=rprec,
        f1=f1_score(rprec, racc),
        num_gt=num_gt,
        num_predictions=len(pred),
        num_precision_predictions=num_sel,
        per_query=per_query,
        matched_iou=total_acc.iou_sum / total_acc.matches if total_acc.matches else 0.0,
        matches=total_acc.matches,
    )


def _query_matches(
    pred: BoxSet, score_t: np.ndarray, assigned: np.ndarray, t: int, gt_t: BoxSet, precision_ratio: float
) -> tuple[MatchCounts, MatchCounts, np.ndarray]:
    """Query t's accuracy and precision matches (module docstring), and the predictions the
    precision counts. score_t: (n,) each prediction's score for t; assigned: (n,) query indices."""
    # Accuracy: the len(gt_t) best-scoring predictions for t, stable on ties.
    top = np.argsort(-score_t, kind="stable")[: len(gt_t)]
    acc = match_boxes(pred[top], gt_t)
    # Precision: predictions for t close to the best of them.
    mine = np.flatnonzero(assigned == t)
    if mine.size:
        best = score_t[mine].max()
        mine = mine[score_t[mine] >= precision_ratio * best]
    return acc, match_boxes(pred[mine], gt_t), mine


def accuracy_matches(pred: BoxSet, scores: np.ndarray, gt: list[BoxSet]) -> list[np.ndarray]:
    """Per query, (N_t,) IoU of each ground-truth box with the prediction matched to it in the
    accuracy matching (NaN where none is)."""
    scores = np.asarray(scores, dtype=np.float64).reshape(len(pred), len(gt))
    out = []
    for t, gt_t in enumerate(gt):
        top = np.argsort(-scores[:, t], kind="stable")[: len(gt_t)]
        iou = iou_matrix(pred[top], gt_t)
        p, g = greedy_match(iou)
        matched = np.full(len(gt_t), np.nan)
        matched[g] = iou[p, g]
        out.append(matched)
    return out


def distance_to_path(xy: np.ndarray, path_xy: np.ndarray) -> np.ndarray:
    """(n,) 2-D distance (metres) of points (n, 2) to a polyline (m, 2) (a single point if m = 1)."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    path = np.asarray(path_xy, dtype=np.float64).reshape(-1, 2)
    if len(path) == 0:
        return np.full(len(xy), np.inf)
    if len(path) == 1:
        return np.linalg.norm(xy - path[0], axis=1)
    a, b = path[:-1], path[1:]
    ab = b - a
    t = np.clip(
        np.einsum("nsk,sk->ns", xy[:, None, :] - a[None], ab) / np.maximum((ab**2).sum(axis=1), 1e-12), 0.0, 1.0
    )
    closest = a[None] + t[..., None] * ab[None]
    return np.linalg.norm(xy[:, None, :] - closest, axis=2).min(axis=1)


def iou_by_distance(
    matched: list[np.ndarray], gt: list[BoxSet], path_xy: np.ndarray, bands: tuple[float, ...] = (5.0, 10.0, 20.0)
) -> list[dict]:
    """Per distance band from the path ([0, 5), [5, 10), [10, 20), [20, inf) metres by default):
    ground-truth objects, how many were matched, and the mean IoU of those matches."""
    centres = [b.center[:, :2] for b in gt if len(b)]
    if not centres:
        return []
    distance = distance_to_path(np.vstack(centres), path_xy)
    iou = np.concatenate([m for m, b in zip(matched, gt) if len(b)])
    edges = (0.0,) + tuple(bands) + (np.inf,)
    out = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        inside = (distance >= lo) & (distance < hi)
        hit = inside & np.isfinite(iou)
        out.append(
            {
                "from_m": lo,
                "to_m": None if np.isinf(hi) else hi,
                "objects": int(inside.sum()),
                "matched": int(hit.sum()),
                "matched_iou": float(iou[hit].mean()) if hit.any() else None,
            }
        )
    return out
