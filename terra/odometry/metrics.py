"""Trajectory error against ground truth: absolute trajectory error (RMSE of positions after the
best rigid alignment, Horn / Umeyama without scale) and drift (final position error, with both
trajectories starting at the same pose, in percent of the distance travelled)."""

from __future__ import annotations

import numpy as np


def rigid_alignment(source: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R (3x3), t (3,) minimising sum |R source_i + t - target_i|^2 for (N, 3) point sets (Kabsch)."""
    mu_s, mu_t = source.mean(axis=0), target.mean(axis=0)
    H = (source - mu_s).T @ (target - mu_t)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return R, mu_t - R @ mu_s


def trajectory_errors(estimate: np.ndarray, reference: np.ndarray) -> dict[str, float]:
    """Errors of (F, 4, 4) estimated poses against (F, 4, 4) reference poses (same frames, same
    start pose): ate_rmse_m, final_error_m, distance_m (reference path length), drift_percent."""
    est, ref = estimate[:, :3, 3], reference[:, :3, 3]
    R, t = rigid_alignment(est, ref) if len(est) >= 3 else (np.eye(3), np.zeros(3))
    aligned = est @ R.T + t
    ate = float(np.sqrt(np.mean(np.sum((aligned - ref) ** 2, axis=1))))
    distance = float(np.sum(np.linalg.norm(np.diff(ref, axis=0), axis=1)))
    final = float(np.linalg.norm(est[-1] - ref[-1]))
    return {
        "ate_rmse_m": ate,
        "final_error_m": final,
        "distance_m": distance,
        "drift_percent": 100.0 * final / distance if distance > 0 else 0.0,
    }
