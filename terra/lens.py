"""Lens distortion models of real calibrations, forwards (projection) and inverse (pixel -> ray).

All functions work on normalised image coordinates (N, 2): (x, y) = (X / Z, Y / Z) of a point
(X, Y, Z) in the camera's optical frame (z forward, x right, y down), before the intrinsics K.
Two model families, named as ROS CameraInfo and OpenCV name them:

- `pinhole` (OpenCV `calib3d`; ROS `plumb_bob` and `rational_polynomial`): coefficient vectors
  of length 0, 4, 5, 8, 12 or 14, in OpenCV's order
  [k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4, tau_x, tau_y]: radial (rational when k4..k6
  are set), tangential, thin prism (s1..s4) and a tilted sensor (tau_x, tau_y, radians).
- `fisheye` (OpenCV `cv::fisheye`; ROS `equidistant`): [k1, k2, k3, k4] with
  theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8), theta the angle of
  the ray from the optical axis (radians).

The inverse is solved numerically (Newton steps) to a residual far below a micro-pixel, not by
OpenCV's five fixed-point iterations, so it is exact enough to round-trip any pixel of a
realistic lens.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

PINHOLE = "pinhole"
FISHEYE = "fisheye"
LENS_MODELS = (PINHOLE, FISHEYE)
COEFFICIENT_COUNTS = {PINHOLE: (0, 4, 5, 8, 12, 14), FISHEYE: (4,)}

# ROS CameraInfo `distortion_model` names -> (our model, accepted coefficient counts).
ROS_DISTORTION_MODELS = {
    "plumb_bob": (PINHOLE, (5,)),
    "rational_polynomial": (PINHOLE, (8,)),
    "equidistant": (FISHEYE, (4,)),
}

_NEWTON_STEPS = 60
_TOLERANCE = 1e-15  # normalised units: about 1e-12 px for a 1000 px focal length


def check_coefficients(model: str, dist: ArrayLike) -> np.ndarray:
    """`dist` as a flat float64 array; ValueError naming the supported lengths when it has none of them."""
    if model not in COEFFICIENT_COUNTS:
        raise ValueError(f"unknown lens model {model!r}; expected one of: {', '.join(LENS_MODELS)}")
    dist = np.asarray(dist, dtype=np.float64).ravel()
    counts = COEFFICIENT_COUNTS[model]
    if dist.size not in counts:
        supported = ", ".join(str(n) for n in counts)
        raise ValueError(f"{model} lens: {dist.size} distortion coefficients; supported lengths: {supported}")
    if not np.all(np.isfinite(dist)):
        raise ValueError(f"{model} lens: distortion coefficients must be finite, got {dist.tolist()}")
    return dist


def has_distortion(dist: ArrayLike) -> bool:
    """Whether the coefficients change anything (an all-zero vector is the ideal lens)."""
    return bool(np.any(np.asarray(dist) != 0))


def distort(xy: ArrayLike, dist: ArrayLike, model: str = PINHOLE) -> np.ndarray:
    """Undistorted normalised coordinates (N, 2) -> distorted normalised coordinates (N, 2)."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    if model == FISHEYE:
        return _fisheye_distort(xy, np.asarray(dist, np.float64))
    if not has_distortion(dist):
        return xy.copy()
    return _pinhole_distort(xy, _padded(dist))


def undistort(xy_distorted: ArrayLike, dist: ArrayLike, model: str = PINHOLE) -> np.ndarray:
    """Inverse of `distort`: distorted normalised coordinates (N, 2) -> undistorted ones.

    Rows where the model cannot be inverted (the lens folds over there, or a fisheye ray at or
    beyond 90 degrees) come back as NaN.
    """
    target = np.asarray(xy_distorted, dtype=np.float64).reshape(-1, 2)
    if model == FISHEYE:
        return _fisheye_undistort(target, np.asarray(dist, np.float64))
    if not has_distortion(dist):
        return target.copy()
    return _pinhole_undistort(target, _padded(dist))


# -- pinhole (OpenCV calib3d) ------------------------------------------------------------------


def _padded(dist: ArrayLike) -> np.ndarray:
    coeffs = np.zeros(14)
    dist = np.asarray(dist, dtype=np.float64).ravel()
    coeffs[: dist.size] = dist
    return coeffs


def tilt_matrix(tau_x: float, tau_y: float) -> np.ndarray:
    """OpenCV's 3x3 projective map of a sensor tilted by tau_x about x, then tau_y about y (radians)."""
    cx, sx, cy, sy = np.cos(tau_x), np.sin(tau_x), np.cos(tau_y), np.sin(tau_y)
    rot_x = np.array([[1.0, 0.0, 0.0], [0.0, cx, sx], [0.0, -sx, cx]])
    rot_y = np.array([[cy, 0.0, -sy], [0.0, 1.0, 0.0], [sy, 0.0, cy]])
    rot = rot_y @ rot_x
    proj_z = np.array([[rot[2, 2], 0.0, -rot[0, 2]], [0.0, rot[2, 2], -rot[1, 2]], [0.0, 0.0, 1.0]])
    return proj_z @ rot


def _pinhole_distort(xy: np.ndarray, c: np.ndarray) -> np.ndarray:
    k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4, tau_x, tau_y = c
    x, y = xy[:, 0], xy[:, 1]
    r2 = x * x + y * y
    r4 = r2 * r2
    radial = (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1.0 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) + s1 * r2 + s2 * r4
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y + s3 * r2 + s4 * r4
    if tau_x or tau_y:
        return _apply_homography(tilt_matrix(tau_x, tau_y), xd, yd)
    return np.stack([xd, yd], axis=1)


def _apply_homography(H: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    w = H[2, 0] * x + H[2, 1] * y + H[2, 2]
    w = np.where(w != 0.0, w, 1.0)
    return np.stack([(H[0, 0] * x + H[0, 1] * y + H[0, 2]) / w, (H[1, 0] * x + H[1, 1] * y + H[1, 2]) / w], axis=1)


def _pinhole_undistort(target: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Newton's method on distort(xy) = target with a central-difference Jacobian, per row.

    The tilt is a homography and is undone exactly first; that point is also the start value.
    """
    start = target
    if c[12] or c[13]:
        start = _apply_homography(np.linalg.inv(tilt_matrix(c[12], c[13])), target[:, 0], target[:, 1])
    xy = start.copy()
    active = np.ones(len(xy), dtype=bool)
    h = 1e-7
    with np.errstate(all="ignore"):
        for _ in range(_NEWTON_STEPS):
            idx = np.flatnonzero(active)
            if idx.size == 0:
                break
            p = xy[idx]
            residual = _pinhole_distort(p, c) - target[idx]
            done = np.abs(residual).max(axis=1) <= _TOLERANCE
            active[idx[done]] = False
            idx, p, residual = idx[~done], p[~done], residual[~done]
            if idx.size == 0:
                break
            dx = (_pinhole_distort(p + [h, 0.0], c) - _pinhole_distort(p - [h, 0.0], c)) / (2 * h)
            dy = (_pinhole_distort(p + [0.0, h], c) - _pinhole_distort(p - [0.0, h], c)) / (2 * h)
            det = dx[:, 0] * dy[:, 1] - dy[:, 0] * dx[:, 1]
            det = np.where(np.abs(det) > 1e-300, det, np.nan)
            step_x = (dy[:, 1] * residual[:, 0] - dy[:, 0] * residual[:, 1]) / det
            step_y = (dx[:, 0] * residual[:, 1] - dx[:, 1] * residual[:, 0]) / det
            xy[idx, 0] = p[:, 0] - step_x
            xy[idx, 1] = p[:, 1] - step_y
        residual = np.abs(_pinhole_distort(xy, c) - target).max(axis=1)
    failed = ~np.isfinite(residual) | (residual > 1e-9)
    xy[failed] = np.nan
    return xy


# -- fisheye (OpenCV cv::fisheye, ROS equidistant) ---------------------------------------------


def _theta_distorted(theta: np.ndarray, k: np.ndarray) -> np.ndarray:
    t2 = theta * theta
    return theta * (1.0 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3]))))


def _fisheye_distort(xy: np.ndarray, k: np.ndarray) -> np.ndarray:
    r = np.hypot(xy[:, 0], xy[:, 1])
    theta = np.arctan(r)
    safe_r = np.where(r > 1e-12, r, 1.0)
    # On the axis the map is the identity to first order: scale -> 1.
    scale = np.where(r > 1e-12, _theta_distorted(theta, k) / safe_r, 1.0)
    return xy * scale[:, None]


def _fisheye_undistort(target: np.ndarray, k: np.ndarray) -> np.ndarray:
    theta_d = np.hypot(target[:, 0], target[:, 1])
    theta = theta_d.copy()
    with np.errstate(all="ignore"):
        for _ in range(_NEWTON_STEPS):
            t2 = theta * theta
            g = _theta_distorted(theta, k) - theta_d
            if np.all(np.abs(g) <= _TOLERANCE):
                break
            dg = 1.0 + t2 * (3 * k[0] + t2 * (5 * k[1] + t2 * (7 * k[2] + t2 * 9 * k[3])))
            theta = theta - g / dg
        ok = (np.abs(_theta_distorted(theta, k) - theta_d) <= 1e-9) & (theta >= 0) & (theta < np.pi / 2)
        scale = np.where(theta_d > 1e-12, np.tan(theta) / np.where(theta_d > 1e-12, theta_d, 1.0), 1.0)
    out = target * scale[:, None]
    out[~ok] = np.nan
    return out
