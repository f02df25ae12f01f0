"""Seeded value noise on a grid (plain NumPy, so results are the same on every machine)."""

from __future__ import annotations

import numpy as np


def value_noise(shape: tuple[int, int], *, period_cells: float,
                rng: np.random.Generator) -> np.ndarray:
    """Smooth random field: random lattice values, smoothstep-interpolated.

    Parameters
    ----------
    shape : (int, int)
        ``(ny, nx)`` of the output.
    period_cells : float
        Lattice spacing in cells (the feature size).
    rng : numpy.random.Generator

    Returns
    -------
    ndarray, float32 (ny, nx)
        Values in ``[-1, 1]``.
    """
    if period_cells <= 0:
        raise ValueError(f"period_cells: must be > 0, got {period_cells}")
    ny, nx = shape
    offset = rng.uniform(0.0, 1.0, size=2)
    gy = int(np.ceil(ny / period_cells + offset[0])) + 2
    gx = int(np.ceil(nx / period_cells + offset[1])) + 2
    lattice = rng.uniform(-1.0, 1.0, size=(gy, gx)).astype(np.float32)
    y = np.arange(ny, dtype=np.float64) / period_cells + offset[0]
    x = np.arange(nx, dtype=np.float64) / period_cells + offset[1]
    iy, ix = np.floor(y).astype(np.int64), np.floor(x).astype(np.int64)
    fy, fx = y - iy, x - ix
    wy = (fy * fy * (3.0 - 2.0 * fy)).astype(np.float32)[:, None]
    wx = (fx * fx * (3.0 - 2.0 * fx)).astype(np.float32)[None, :]
    rows = lattice[:, ix] * (1 - wx) + lattice[:, ix + 1] * wx  # (gy, nx), separable
    return (rows[iy] * (1 - wy) + rows[iy + 1] * wy).astype(np.float32, copy=False)


def fbm(shape: tuple[int, int], *, period_cells: float, octaves: int,
        rng: np.random.Generator, persistence: float = 0.5) -> np.ndarray:
    """Fractal sum of :func:`value_noise` octaves (period halves, amplitude times persistence).

    Returns
    -------
    ndarray, float32 (ny, nx)
        Roughly in ``[-1, 1]`` (normalised by the sum of amplitudes).
    """
    if octaves < 1:
        raise ValueError(f"octaves: must be >= 1, got {octaves}")
    total = np.zeros(shape, np.float32)
    amplitude, norm, period = 1.0, 0.0, float(period_cells)
    for _ in range(octaves):
        total += np.float32(amplitude) * value_noise(shape, period_cells=max(period, 1.0), rng=rng)
        norm += amplitude
        amplitude *= persistence
        period /= 2.0
    return total / np.float32(norm)


def smooth_wander(n: int, *, rng: np.random.Generator, period_frames: tuple[float, float],
                  components: int = 3) -> np.ndarray:
    """A smooth random signal in ``[-1, 1]``: weighted sinusoids with random periods/phases.

    Returns
    -------
    ndarray, float64 (n,)
    """
    lo, hi = period_frames
    periods = rng.uniform(lo, hi, size=components)
    phases = rng.uniform(0.0, 2.0 * np.pi, size=components)
    weights = rng.uniform(0.5, 1.0, size=components)
    weights /= weights.sum()
    t = np.arange(n, dtype=np.float64)[:, None]
    return (weights * np.sin(2.0 * np.pi * t / periods + phases)).sum(axis=1)
