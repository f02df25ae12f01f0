"""The dataset of the weather world: which frames exist, and rendering them.

Frames are planned first (poses and weather per frame, all from named streams of the seed),
then rendered in batches. Training frames come first (condition by condition), then the test
drives (route by route, condition by condition); the row of a frame is its ``frame`` id.

Random streams (see :mod:`.rng`):

- training frame ``i`` of condition ``c``: pose ``("train", "pose", c, i)`` (``paired``:
  ``("train", "pose", i)``, shared by the conditions), weather ``("train", "weather", c, i)``;
- drive of ``route`` under ``c``: path ``("test", route, c, "path")``, weather
  ``("test", route, c, "weather")``; a repeat drive (calibration, the loops' lap 2) adds its
  name.

Looping routes (``data.test.loops``, :class:`~cmal_lcd.data.world.config.LoopSpec`): lap 1 and
lap 2 of a test route are two drives of the dataset, listed in ``dataset.json`` ``loops`` as
``[route, lap1_drive, lap2_drive, name]`` (``name`` = ``<lap1 condition>-<lap2 condition>``).
A weather-change loop uses the route's drives under its two conditions; the same-weather
control needs a second drive of its condition, rendered here as ``<route>/<control>_lap2``
(split ``test``, right after the route's other drives). That drive is in no ``pairs`` entry,
so the two-drive evaluation never sees it.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import pandas as pd

from cmal_lcd.data.store import FRAME_COLUMNS
from cmal_lcd.data.world.camera import Poses, drive_poses, train_pose
from cmal_lcd.data.world.config import LAP2, DataConfig, drive_name, pair_name
from cmal_lcd.data.world.render import Renderer, make_renderer
from cmal_lcd.data.world.rng import stream_rng
from cmal_lcd.data.world.weather import (WeatherParams, apply_weather, sample_drive_weather,
                                         sample_frame_weather)
from cmal_lcd.data.world.world import World, build_world

logger = logging.getLogger(__name__)



@dataclass(frozen=True)
class FrameGroup:
    """Frames rendered together: the training frames of one condition, or one drive.

    Attributes
    ----------
    split : str
        ``"train"``, ``"test"`` or ``"val"`` (a validation route's drive).
    condition : str
    route, drive : str
        Empty for training frames.
    poses : Poses
    weather : WeatherParams
    """

    split: str
    condition: str
    route: str
    drive: str
    poses: Poses
    weather: WeatherParams

    def __len__(self) -> int:
        return len(self.poses)


def plan_train(config: DataConfig, world: World, *, seed: int) -> list[FrameGroup]:
    """Training frames: ``train_per_condition`` random road poses per condition.

    Returns
    -------
    list of FrameGroup
        One per condition, in label order.
    """
    roads = [world.roads[name] for name in world.train_roads]
    spec = config.train
    groups = []
    for condition, params in config.conditions.items():
        n = config.train_per_condition
        xyh = np.empty((n, 3))
        for i in range(n):
            key = ("train", "pose", i) if spec.paired else ("train", "pose", condition, i)
            xyh[i] = train_pose(roads, stream_rng(seed, *key),
                                lane_width_m=config.world.lane_width_m,
                                lateral_jitter_m=spec.lateral_jitter_m,
                                heading_jitter_deg=spec.heading_jitter_deg)
        weather = sample_frame_weather(
            params, [stream_rng(seed, "train", "weather", condition, i) for i in range(n)])
        nan = np.full(n, np.nan)
        poses = Poses(x=xyh[:, 0], y=xyh[:, 1], heading=xyh[:, 2], s=nan, time=nan)
        groups.append(FrameGroup("train", condition, "", "", poses, weather))
    return groups


def plan_drive(config: DataConfig, world: World, route: str, condition: str, *, seed: int,
               repeat: str | None = None) -> FrameGroup:
    """One drive of ``route`` under ``condition`` (over that condition's window).

    Parameters
    ----------
    repeat : str, optional
        Name of an extra, independently wandering drive of the same route and condition (used
        by the calibration for same-weather baselines; never part of the dataset).
    """
    known = {**config.test.routes, **config.test.validation_routes}
    if route not in known:
        raise ValueError(f"route: unknown route {route!r}; known: {list(known)}")
    if condition not in config.conditions:
        raise ValueError(f"condition: unknown condition {condition!r}; "
                         f"known: {list(config.conditions)}")
    extra = (repeat,) if repeat else ()
    test = config.test
    poses = drive_poses(world.roads[route], window=test.windows[condition],
                        frame_spacing_m=test.frame_spacing_m, speed_mps=test.speed_mps,
                        wander=test.wander, lane_width_m=config.world.lane_width_m,
                        rng=stream_rng(seed, "test", route, condition, "path", *extra))
    weather_rng = stream_rng(seed, "test", route, condition, "weather", *extra)
    weather = sample_drive_weather(config.conditions[condition], n=len(poses), rng=weather_rng,
                                   jitter=test.weather_jitter,
                                   period_frames=test.wander.period_frames)
    name = drive_name(route, condition) + (f"_{repeat}" if repeat else "")
    split = "val" if route in config.test.validation_routes else "test"
    return FrameGroup(split, condition, route, name, poses, weather)


def plan_dataset(config: DataConfig, world: World, *, seed: int) -> list[FrameGroup]:
    """All frame groups in row order: training, every test route's drives (then the
    same-weather control's lap-2 drive when ``data.test.loops.control`` is set), then every
    validation route's drives (split ``"val"``)."""
    groups = plan_train(config, world, seed=seed)
    control = config.test.loops.control
    for route in [*config.test.routes, *config.test.validation_routes]:
        for condition in config.conditions:
            groups.append(plan_drive(config, world, route, condition, seed=seed))
        if control is not None and route in config.test.routes:
            groups.append(plan_drive(config, world, route, control, seed=seed, repeat=LAP2))
    return groups


def loop_entries(config: DataConfig) -> list[list[str]]:
    """``[route, lap1_drive, lap2_drive, name]`` of every looping route of the test routes:
    the weather-change loops (``data.test.loops.pairs``), then the same-weather control."""
    loops = config.test.loops
    laps = [(a, b, pair_name(a, b)) for a, b in loops.pairs]
    if loops.control is not None:
        laps.append((loops.control, f"{loops.control}_{LAP2}",
                     pair_name(loops.control, loops.control)))
    return [[route, drive_name(route, first), drive_name(route, second), name]
            for route in config.test.routes for first, second, name in laps]


def render_group(renderer: Renderer, group: FrameGroup, *, supersample: int,
                 sky_distance_m: float, batch_size: int = 64,
                 progress: bool = True) -> np.ndarray:
    """Render and weather the frames of ``group``.

    ``progress``: show a bar on a terminal, or log a line every 30 s otherwise
    (:class:`cmal_lcd.progress.Progress`); the images do not depend on it.

    Returns
    -------
    ndarray, uint8 (N, H, W, 3)
        ``H, W`` = the renderer's size divided by ``supersample``.
    """
    from cmal_lcd.progress import Progress

    h, w = (v // supersample for v in renderer.image_size)
    out = np.empty((len(group), h, w, 3), np.uint8)
    name = "/".join(part for part in (group.route, group.drive or group.condition) if part)
    bar = Progress(len(group), desc=f"render {group.split} {name}", unit="frame",
                   logger=logger, terminal=None if progress else False,
                   interval=30.0 if progress else float("inf"))
    with bar:
        for start in range(0, len(group), batch_size):
            idx = slice(start, min(start + batch_size, len(group)))
            weather = group.weather.subset(idx)
            gbuf = renderer.render(group.poses.x[idx], group.poses.y[idx],
                                   group.poses.heading[idx],
                                   sun_direction=weather.sun_direction())
            out[idx] = apply_weather(gbuf, weather, supersample=supersample,
                                     sky_distance_m=sky_distance_m)
            bar.update(idx.stop - idx.start)
    return out


def make_world_renderer(config: DataConfig, *, seed: int) -> tuple[World, Renderer]:
    """Build the world and its renderer at the super-sampled resolution."""
    world = build_world(config, seed=seed)
    h, w = config.image_size
    renderer = make_renderer(config.renderer, world, config.camera,
                             image_size=(h * config.supersample, w * config.supersample))
    return world, renderer


def frame_table(groups: list[FrameGroup]) -> pd.DataFrame:
    """The ``frames.csv`` table of ``groups`` in row order (columns :data:`FRAME_COLUMNS`)."""
    parts = []
    for g in groups:
        n = len(g)
        parts.append(pd.DataFrame({
            "split": [g.split] * n, "route": [g.route] * n, "drive": [g.drive] * n,
            "condition": [g.condition] * n, "x": g.poses.x, "y": g.poses.y,
            "heading": g.poses.heading, "time": g.poses.time, "s": g.poses.s}))
    frames = pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(
        columns=list(FRAME_COLUMNS[1:]))
    frames.insert(0, "frame", np.arange(len(frames), dtype=np.int64))
    return frames[list(FRAME_COLUMNS)]


def dataset_meta(config: DataConfig, world: World, groups: list[FrameGroup], *, seed: int,
                 config_dict: dict) -> dict:
    """``dataset.json`` content: conditions (label order), routes, drives, pairs, config."""
    drives = [{"name": g.drive, "route": g.route, "condition": g.condition, "frames": len(g),
               "window": list(config.test.windows[g.condition]),
               "length_m": float(g.poses.s[-1] - g.poses.s[0]) if len(g) else 0.0}
              for g in groups if g.split in ("test", "val")]

    def route_pairs(routes):
        return [[route, drive_name(route, ref), drive_name(route, query), pair_name(ref, query)]
                for route in routes for ref, query in config.test.pairs]

    return {
        "kind": config.kind,
        "image_size": list(config.image_size),
        "conditions": config.condition_names,
        "routes": list(config.test.routes),
        "drives": drives,
        "pairs": route_pairs(config.test.routes),
        "loops": loop_entries(config),
        "loop_exclude_frames": config.test.loops.exclude_frames,
        "validation_routes": list(config.test.validation_routes),
        "validation_pairs": route_pairs(config.test.validation_routes),
        "ground_truth": "poses",
        "frame_spacing_m": config.test.frame_spacing_m,
        "train_per_condition": config.train_per_condition,
        "regions": {"train": list(world.region_box("train")),
                    "test": list(world.region_box("test"))},
        "seed": int(seed),
        "config": config_dict,
    }
