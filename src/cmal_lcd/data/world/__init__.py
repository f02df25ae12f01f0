"""The procedural GTAV-style weather world: terrain, roads, objects, camera, renderer, weather.

Typical use (what the ``dataset`` stage does)::

    config = DataConfig.from_config(cfg.data)
    world, renderer = make_world_renderer(config, seed=cfg.seed)
    for group in plan_dataset(config, world, seed=cfg.seed):
        images = render_group(renderer, group, supersample=config.supersample,
                              sky_distance_m=config.camera.max_distance_m)

Geometry (:mod:`.world`, :mod:`.render`) never depends on the weather; the weather
(:mod:`.weather`) is applied to the renderer's G-buffer.
"""

from cmal_lcd.data.world.camera import Poses, drive_poses, train_pose
from cmal_lcd.data.world.condition import ConditionParams
from cmal_lcd.data.world.config import DataConfig, drive_name, pair_name
from cmal_lcd.data.world.dataset import (FrameGroup, frame_table, make_world_renderer,
                                         plan_dataset, plan_drive, plan_train, render_group)
from cmal_lcd.data.world.render import (RENDERERS, GBuffer, HeightmapRenderer, Renderer,
                                        make_renderer)
from cmal_lcd.data.world.rng import stream_rng
from cmal_lcd.data.world.weather import (WeatherParams, apply_weather, sample_drive_weather,
                                         sample_frame_weather)
from cmal_lcd.data.world.world import World, build_world

__all__ = [
    "RENDERERS", "ConditionParams", "DataConfig", "FrameGroup", "GBuffer", "HeightmapRenderer",
    "Poses", "Renderer", "WeatherParams", "World", "apply_weather", "build_world",
    "drive_name", "drive_poses", "frame_table", "make_renderer", "make_world_renderer",
    "pair_name", "plan_dataset", "plan_drive", "plan_train", "render_group",
    "sample_drive_weather", "sample_frame_weather", "stream_rng", "train_pose",
]
