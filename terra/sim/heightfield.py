"""The ground: a smooth analytic height field z = h(x, y) (map frame, metres), optionally plus a
raster of step offsets (`StepRaster`: curbs, curb cuts, ramps, mounds; terra/sim/geometry.py).

h is a sum of a few long plane waves, so slopes stay at a few degrees and the bound on the slope,
L = sum(a_i |k_i|), gives a safe marching step: along a ray, the height of the ray above the ground
can fall no faster than L |d_xy| - d_z per metre travelled. The offsets are constant within each
raster cell (vertical walls between cells); the ray caster walks their cells where a ray comes
within the largest offset of its block (terra/sim/kernels.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class StepRaster:
    """Ground offsets (H, W) float64 metres added to the smooth height, one value per cell: cell
    (r, c) covers x in [x0 + c res, x0 + (c+1) res), y in [y0 + r res, ...) (the terrain raster's
    layout); a point beyond the raster takes the nearest edge cell's offset (no wall at the edge).

    block_max (Hb, Wb): the largest offset of each block of `block` x `block` cells (32: 8 m on
    0.25 m cells, the fastest of 4 to 64 on the tiny site), the envelope the ray caster marches
    against before it walks cells. Masks (H, W) bool of what was built:
    curb_cut (ramps from a road up to a raised walk), ramp (ramps beside stairs), hill (the steep
    hill), lawn (gently sloped lawns)."""

    offsets: np.ndarray
    origin: np.ndarray
    resolution: float
    curb_cut: np.ndarray
    ramp: np.ndarray
    hill: np.ndarray
    lawn: np.ndarray
    block: int = 32

    def __post_init__(self) -> None:
        h, w = self.offsets.shape
        b = self.block
        padded = np.full((-(-h // b) * b, -(-w // b) * b), -np.inf)
        padded[:h, :w] = self.offsets
        self.block_max = padded.reshape(padded.shape[0] // b, b, padded.shape[1] // b, b).max(axis=(1, 3))

    def at(self, xy: np.ndarray) -> np.ndarray:
        """Offsets (N,) metres at map-frame points (N, 2)."""
        rc = np.floor((np.asarray(xy, dtype=np.float64)[..., :2] - self.origin) / self.resolution).astype(np.int64)
        h, w = self.offsets.shape
        return self.offsets[np.clip(rc[..., 1], 0, h - 1), np.clip(rc[..., 0], 0, w - 1)]

    def grid(self) -> np.ndarray:
        """(5,) float64 the ray caster reads: x0, y0, resolution, block, largest offset."""
        return np.array(
            [self.origin[0], self.origin[1], self.resolution, float(self.block), float(self.offsets.max())], np.float64
        )


@dataclass
class Heightfield:
    """h(x, y) = base + sum_i amplitude_i * sin(k_i . (x, y) + phase_i).

    amplitude: (W,) metres. wavevector: (W, 2) radians per metre. phase: (W,) radians. steps: offsets
    added cell by cell (None: the smooth field alone).
    """

    amplitude: np.ndarray
    wavevector: np.ndarray
    phase: np.ndarray
    base: float = 0.0
    steps: StepRaster | None = None

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
        """Ground height (metres) at map-frame points (N, 2), step offsets included; float64."""
        xy = np.asarray(xy, dtype=np.float64)
        arg = xy[..., :2] @ self.wavevector.T + self.phase
        smooth = self.base + np.sin(arg) @ self.amplitude
        return smooth if self.steps is None else smooth + self.steps.at(xy)

    def gradient(self, xy: np.ndarray) -> np.ndarray:
        """(N, 2) gradient dh/dx, dh/dy of the smooth field (the step offsets are flat within a cell)."""
        xy = np.asarray(xy, dtype=np.float64)
        arg = xy[..., :2] @ self.wavevector.T + self.phase
        return (np.cos(arg) * self.amplitude) @ self.wavevector

    def normal(self, xy: np.ndarray) -> np.ndarray:
        """(N, 3) upward unit normals of the ground."""
        g = self.gradient(xy)
        n = np.concatenate([-g, np.ones((g.shape[0], 1))], axis=1)
        return n / np.linalg.norm(n, axis=1, keepdims=True)
