"""Camera poses: random training poses along roads and smoothly wandering test drives.

Cars drive on the right: the lane centre is half a lane width right of the centreline in the
direction of travel. Headings are radians counter-clockwise from ``+x``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cmal_lcd.data.world.config import WanderSpec
from cmal_lcd.data.world.noise import smooth_wander
from cmal_lcd.data.world.roads import Road


@dataclass(frozen=True)
class Poses:
    """Camera ground poses of a batch of frames.

    Attributes
    ----------
    x, y : ndarray, float64 (N,)
        Position, metres.
    heading : ndarray, float64 (N,)
        Radians counter-clockwise from ``+x``.
    s : ndarray, float64 (N,)
        Arc length along the route (NaN for training frames).
    time : ndarray, float64 (N,)
        Seconds since the start of the drive (NaN for training frames).
    """

    x: np.ndarray
    y: np.ndarray
    heading: np.ndarray
    s: np.ndarray
    time: np.ndarray

    def __len__(self) -> int:
        return len(self.x)

    @staticmethod
    def concatenate(items: list["Poses"]) -> "Poses":
        """All poses of ``items`` in order."""
        if not items:
            empty = np.zeros(0)
            return Poses(empty, empty, empty, empty, empty)
        return Poses(*(np.concatenate([getattr(p, f) for p in items])
                       for f in ("x", "y", "heading", "s", "time")))


def lane_pose(road: Road, s: np.ndarray, *, direction: np.ndarray, lateral: np.ndarray,
              heading_offset: np.ndarray, lane_width_m: float) -> tuple[np.ndarray, ...]:
    """Pose in the right-hand lane at arc lengths ``s``.

    Parameters
    ----------
    road : Road
    s : ndarray, float (N,)
        Arc length.
    direction : ndarray, float (N,)
        ``+1`` along increasing ``s``, ``-1`` against.
    lateral : ndarray, float (N,)
        Extra offset to the left of the lane centre, metres.
    heading_offset : ndarray, float (N,)
        Radians added to the direction of travel.
    lane_width_m : float

    Returns
    -------
    x, y, heading : ndarray, float64 (N,)
    """
    xy, tangent, _ = road.at(s)
    left = -direction * lane_width_m / 2.0 + lateral  # offset left of the centreline
    x = xy[:, 0] - tangent[:, 1] * left
    y = xy[:, 1] + tangent[:, 0] * left
    heading = np.arctan2(direction * tangent[:, 1], direction * tangent[:, 0]) + heading_offset
    return x, y, np.mod(heading, 2.0 * np.pi)


def train_pose(roads: list[Road], rng: np.random.Generator, *, lane_width_m: float,
               lateral_jitter_m: float, heading_jitter_deg: float) -> tuple[float, float, float]:
    """One random training pose: a road (chance proportional to length), a uniform arc
    length, a random direction of travel, uniform jitter in lateral offset and heading.

    Returns
    -------
    x, y, heading : float
    """
    lengths = np.array([r.length for r in roads])
    road = roads[int(rng.choice(len(roads), p=lengths / lengths.sum()))]
    s = rng.uniform(0.0, road.length)
    direction = rng.choice([-1.0, 1.0])
    lateral = rng.uniform(-lateral_jitter_m, lateral_jitter_m)
    dh = np.deg2rad(rng.uniform(-heading_jitter_deg, heading_jitter_deg))
    x, y, heading = lane_pose(road, np.array([s]), direction=np.array([direction]),
                              lateral=np.array([lateral]), heading_offset=np.array([dh]),
                              lane_width_m=lane_width_m)
    return float(x[0]), float(y[0]), float(heading[0])


def drive_poses(road: Road, *, window: tuple[float, float], frame_spacing_m: float,
                speed_mps: float, wander: WanderSpec, lane_width_m: float,
                rng: np.random.Generator) -> Poses:
    """A drive along ``road`` over the arc-length ``window`` with smooth per-drive wander.

    The speed factor wanders in ``wander.speed`` (frame ``k+1`` lies ``frame_spacing_m`` times
    the factor beyond frame ``k``), the lateral offset by up to ``wander.lateral_m`` and the
    heading by up to ``wander.heading_deg``; the first frame starts at a random fraction of
    one spacing into the window, so two drives never sample the same places.

    Parameters
    ----------
    road : Road
    window : (float, float)
        Fractions of the road's length.
    frame_spacing_m, speed_mps : float
        Spacing at the nominal speed, and the nominal speed (sets ``time``).
    wander : WanderSpec
    lane_width_m : float
    rng : numpy.random.Generator
        The drive's own stream.

    Returns
    -------
    Poses
    """
    s_start, s_end = window[0] * road.length, window[1] * road.length
    lo, hi = wander.speed
    n_max = int(np.ceil((s_end - s_start) / (frame_spacing_m * lo))) + 2
    speed = lo + (hi - lo) * (0.5 + 0.5 * smooth_wander(n_max, rng=rng,
                                                         period_frames=wander.period_frames))
    lateral = wander.lateral_m * smooth_wander(n_max, rng=rng, period_frames=wander.period_frames)
    dh = np.deg2rad(wander.heading_deg) * smooth_wander(n_max, rng=rng,
                                                        period_frames=wander.period_frames)
    s0 = s_start + rng.uniform(0.0, frame_spacing_m)
    s = s0 + frame_spacing_m * np.concatenate([[0.0], np.cumsum(speed[:-1])])
    n = int(np.searchsorted(s, s_end, side="right"))
    s = s[:n]
    ones = np.ones(n)
    x, y, heading = lane_pose(road, s, direction=ones, lateral=lateral[:n],
                              heading_offset=dh[:n], lane_width_m=lane_width_m)
    time = np.arange(n) * (frame_spacing_m / speed_mps)
    return Poses(x=x, y=y, heading=heading, s=s, time=time)
