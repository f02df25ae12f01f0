"""Roads: meandering centrelines, their height profile and the per-cell road coordinates."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

#: Spacing of the centreline samples, metres.
CENTRELINE_STEP_M = 0.5


@dataclass(frozen=True)
class Road:
    """A road as a densely sampled centreline, driven in the direction of increasing ``s``.

    Attributes
    ----------
    name, style : str
    points : ndarray, float64 (M, 2)
        Centreline ``x, y`` in metres, every :data:`CENTRELINE_STEP_M` of arc length.
    s : ndarray, float64 (M,)
        Arc length of each sample.
    tangent : ndarray, float64 (M, 2)
        Unit direction of travel.
    z : ndarray, float64 (M,)
        Height of the road surface.
    """

    name: str
    style: str
    points: np.ndarray
    s: np.ndarray
    tangent: np.ndarray
    z: np.ndarray

    @property
    def length(self) -> float:
        """Arc length, metres."""
        return float(self.s[-1])

    def at(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Centreline point, unit tangent and height at arc lengths ``s`` (clipped to the road).

        Parameters
        ----------
        s : ndarray, float (K,)

        Returns
        -------
        xy : ndarray, float64 (K, 2)
        tangent : ndarray, float64 (K, 2)
        z : ndarray, float64 (K,)
        """
        s = np.clip(np.asarray(s, np.float64), 0.0, self.length)
        xy = np.stack([np.interp(s, self.s, self.points[:, 0]),
                       np.interp(s, self.s, self.points[:, 1])], axis=1)
        angle = np.unwrap(np.arctan2(self.tangent[:, 1], self.tangent[:, 0]))
        theta = np.interp(s, self.s, angle)
        tangent = np.stack([np.cos(theta), np.sin(theta)], axis=1)
        return xy, tangent, np.interp(s, self.s, self.z)


def meander_centreline(*, x0: float, y0: float, length_m: float, meander_m: float,
                       rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A road heading north from ``(x0, y0)``, meandering sideways by at most ``meander_m``.

    ``x(y) = x0 + meander_m * sum_i w_i sin(2 pi (y - y0) / P_i + phi_i)`` with three random
    periods ``P_i`` in [180, 600] m and weights summing to one, resampled every
    :data:`CENTRELINE_STEP_M` of arc length.

    Returns
    -------
    points : ndarray, float64 (M, 2)
    s : ndarray, float64 (M,)
    tangent : ndarray, float64 (M, 2)
    """
    periods = rng.uniform(180.0, 600.0, size=3)
    phases = rng.uniform(0.0, 2.0 * np.pi, size=3)
    weights = rng.uniform(0.5, 1.0, size=3)
    weights /= weights.sum()
    y = y0 + np.arange(0.0, length_m + 2.0, 0.25)
    x = x0 + meander_m * (weights[None, :] * np.sin(
        2.0 * np.pi * (y[:, None] - y0) / periods[None, :] + phases[None, :])).sum(axis=1)
    seg = np.hypot(np.diff(x), np.diff(y))
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    s = np.arange(0.0, length_m + 1e-9, CENTRELINE_STEP_M)
    points = np.stack([np.interp(s, arc, x), np.interp(s, arc, y)], axis=1)
    grad = np.gradient(points, axis=0)
    tangent = grad / np.linalg.norm(grad, axis=1, keepdims=True)
    return points, s, tangent


def road_profile(ground_z: np.ndarray, *, smooth_m: float = 25.0) -> np.ndarray:
    """Road surface height from the terrain under the centreline, smoothed along the road.

    Parameters
    ----------
    ground_z : ndarray, float (M,)
        Terrain height under each centreline sample.

    Returns
    -------
    ndarray, float64 (M,)
    """
    sigma = smooth_m / CENTRELINE_STEP_M
    return ndimage.gaussian_filter1d(np.asarray(ground_z, np.float64), sigma, mode="nearest")


@dataclass(frozen=True)
class RoadField:
    """For every cell, coordinates relative to the nearest road sample.

    Attributes
    ----------
    road : ndarray, int16 (n, n)
        Index of the nearest road (in the order given to :func:`road_field`).
    s : ndarray, float32 (n, n)
        Arc length of the nearest point on that road.
    lateral : ndarray, float32 (n, n)
        Signed offset from the centreline, metres (> 0 = left of the direction of travel).
    distance : ndarray, float32 (n, n)
        Distance to the nearest centreline sample (beyond a road's ends, the distance to the
        end, not to the centreline's extension).
    z : ndarray, float32 (n, n)
        Road surface height at the nearest sample.
    """

    road: np.ndarray
    s: np.ndarray
    lateral: np.ndarray
    distance: np.ndarray
    z: np.ndarray


def road_field(roads: list[Road], *, n_cells: int, cell_m: float) -> RoadField:
    """Nearest-road coordinates of every cell centre (exact Euclidean distance transform).

    Parameters
    ----------
    roads : list of Road
    n_cells : int
        Cells per side.
    cell_m : float
        Cell size, metres.
    """
    points = np.concatenate([r.points for r in roads])
    tangents = np.concatenate([r.tangent for r in roads])
    s = np.concatenate([r.s for r in roads])
    z = np.concatenate([r.z for r in roads])
    which = np.concatenate([np.full(len(r.s), i, np.int16) for i, r in enumerate(roads)])
    ij = np.floor(points / cell_m).astype(np.int64)
    inside = (ij >= 0).all(axis=1) & (ij < n_cells).all(axis=1)
    marks = np.full((n_cells, n_cells), -1, np.int64)
    idx = np.nonzero(inside)[0]
    marks[ij[idx, 1], ij[idx, 0]] = idx
    if not inside.any():
        raise ValueError("roads: no road lies inside the world")
    _, (iy, ix) = ndimage.distance_transform_edt(marks < 0, return_indices=True)
    nearest = marks[iy, ix]
    centres = (np.arange(n_cells, dtype=np.float64) + 0.5) * cell_m
    dx = centres[None, :] - points[nearest, 0]
    dy = centres[:, None] - points[nearest, 1]
    tx, ty = tangents[nearest, 0], tangents[nearest, 1]
    lateral = tx * dy - ty * dx
    along = tx * dx + ty * dy
    return RoadField(road=which[nearest], s=(s[nearest] + along).astype(np.float32),
                     lateral=lateral.astype(np.float32),
                     distance=np.hypot(dx, dy).astype(np.float32), z=z[nearest].astype(np.float32))
