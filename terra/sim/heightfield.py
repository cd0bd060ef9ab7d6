"""The ground: a smooth analytic height field z = h(x, y) (map frame, metres).

h is a sum of a few long plane waves, so slopes stay at a few degrees and the bound on the slope,
L = sum(a_i |k_i|), gives a safe marching step: along a ray, the height of the ray above the ground
can fall no faster than L |d_xy| - d_z per metre travelled.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Heightfield:
    """h(x, y) = base + sum_i amplitude_i * sin(k_i . (x, y) + phase_i).

    amplitude: (W,) metres. wavevector: (W, 2) radians per metre. phase: (W,) radians.
    """

    amplitude: np.ndarray
    wavevector: np.ndarray
    phase: np.ndarray
    base: float = 0.0

    @classmethod
    def random(cls, rng: np.random.Generator, relief: float = 1.0) -> Heightfield:
        """Three waves of wavelength 70-180 m; with relief 1 the slope stays under about 6 degrees."""
        wavelengths = np.array([180.0, 110.0, 70.0])
        amplitude = relief * np.array([1.2, 0.6, 0.3])
        angles = rng.uniform(0.0, 2.0 * np.pi, size=3)
        k = (2.0 * np.pi / wavelengths)[:, None] * np.stack([np.cos(angles), np.sin(angles)], axis=1)
        return cls(amplitude, k, rng.uniform(0.0, 2.0 * np.pi, size=3))

    @property
    def slope_bound(self) -> float:
        """Upper bound of |grad h| (dimensionless)."""
        return float(np.sum(np.abs(self.amplitude) * np.linalg.norm(self.wavevector, axis=1)))

    def height(self, xy: np.ndarray) -> np.ndarray:
        """Ground height (metres) at map-frame points (N, 2); float64."""
        xy = np.asarray(xy, dtype=np.float64)
        arg = xy[..., :2] @ self.wavevector.T + self.phase
        return self.base + np.sin(arg) @ self.amplitude

    def gradient(self, xy: np.ndarray) -> np.ndarray:
        """(N, 2) gradient dh/dx, dh/dy."""
        xy = np.asarray(xy, dtype=np.float64)
        arg = xy[..., :2] @ self.wavevector.T + self.phase
        return (np.cos(arg) * self.amplitude) @ self.wavevector

    def normal(self, xy: np.ndarray) -> np.ndarray:
        """(N, 3) upward unit normals of the ground."""
        g = self.gradient(xy)
        n = np.concatenate([-g, np.ones((g.shape[0], 1))], axis=1)
        return n / np.linalg.norm(n, axis=1, keepdims=True)
