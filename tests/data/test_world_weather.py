"""Weather: per-frame draws within the condition's ranges and the physical image model."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cmal_lcd.data.world import (ConditionParams, GBuffer, sample_drive_weather,
                                 sample_frame_weather, stream_rng)
from cmal_lcd.data.world import materials as M
from cmal_lcd.data.world.condition import RANGE_PARAMS
from cmal_lcd.data.world.weather import WeatherParams, camera_image, shade_radiance


def gbuffer(depths: list[float], *, material: int = M.GRASS, albedo: float = 0.3) -> GBuffer:
    """One frame, one row: level ground pixels at the given ranges, lit from above."""
    w = len(depths)
    normal = np.zeros((1, 1, w, 3), np.float32)
    normal[..., 2] = 1.0
    view = np.zeros((1, 1, w, 3), np.float32)
    view[..., 0] = 1.0
    return GBuffer(albedo=np.full((1, 1, w, 3), albedo, np.float32), normal=normal,
                   depth=np.array([[depths]], np.float32),
                   material=np.full((1, 1, w), material, np.uint8),
                   sun_visibility=np.ones((1, 1, w), np.float32), view=view,
                   puddle=np.zeros((1, 1, w), np.float32), horizon=-10.0)


def fixed_weather(**values: float) -> WeatherParams:
    """One frame of a neutral condition with white colours and the given values."""
    condition = ConditionParams.from_config("test", {
        "ambient_color": [1, 1, 1], "airlight_color": [1, 1, 1], "sun_color": [1, 1, 1],
        **{k: [v, v] for k, v in values.items()}})
    return WeatherParams("test", {k: np.array([condition.ranges[k][0]]) for k in RANGE_PARAMS},
                         {k: np.asarray(v, float) for k, v in condition.colors.items()},
                         np.array([7], np.uint64))


def test_fog_follows_koschmieder():
    depths = [0.0, 10.0, 50.0, 200.0]
    beta, airlight, ambient = 0.02, 0.9, 1.0
    out = shade_radiance(gbuffer(depths), fixed_weather(fog_beta=beta, airlight=airlight,
                                                        ambient=ambient, sun_intensity=0.0),
                         sky_distance_m=300.0)
    surface = 0.3 * ambient * (0.6 + 0.4 * 1.0)  # albedo times hemisphere light, normal up
    for j, d in enumerate(depths):
        t = math.exp(-beta * d)
        assert out[0, 0, j, 0] == pytest.approx(surface * t + airlight * (1 - t), rel=1e-5)


def test_direct_sun_lights_surfaces_facing_it_and_not_shadows():
    buffer = gbuffer([5.0, 5.0])
    buffer.sun_visibility[0, 0, 1] = 0.0
    weather = fixed_weather(sun_intensity=3.0, sun_elevation_deg=90.0, ambient=0.5, fog_beta=0.0)
    out = shade_radiance(buffer, weather, sky_distance_m=300.0)
    assert out[0, 0, 0, 0] == pytest.approx(0.3 * (3.0 + 0.5), rel=1e-5)
    assert out[0, 0, 1, 0] == pytest.approx(0.3 * 0.5, rel=1e-5)


def test_a_wet_road_is_darker_and_reflects_the_sky():
    dry = shade_radiance(gbuffer([5.0], material=M.ROAD), fixed_weather(fog_beta=0.0),
                         sky_distance_m=300.0)
    # grazing view of level ground: strong Fresnel reflection of the (bright) sky
    buffer = gbuffer([5.0], material=M.ROAD)
    buffer.view[..., 2] = -0.05
    wet = shade_radiance(buffer, fixed_weather(fog_beta=0.0, wetness=1.0, sky_brightness=1.0),
                         sky_distance_m=300.0)
    steep = gbuffer([5.0], material=M.ROAD)
    steep.view[0, 0, 0] = [0.0, 0.0, -1.0]
    wet_steep = shade_radiance(steep, fixed_weather(fog_beta=0.0, wetness=1.0),
                               sky_distance_m=300.0)
    assert wet_steep[0, 0, 0, 0] < dry[0, 0, 0, 0]
    assert wet[0, 0, 0, 0] > wet_steep[0, 0, 0, 0]


def test_frame_weather_is_drawn_within_the_ranges():
    condition = ConditionParams.from_config("c", {"fog_beta": [0.01, 0.02],
                                                  "sun_azimuth_deg": [100.0, 200.0]})
    weather = sample_frame_weather(condition, [stream_rng(0, "t", i) for i in range(50)])
    assert len(weather) == 50
    for name, (lo, hi) in condition.ranges.items():
        assert ((weather.values[name] >= lo) & (weather.values[name] <= hi)).all(), name
    assert weather.values["fog_beta"].std() > 0  # not one fixed transform
    assert len(set(weather.values["sun_azimuth_deg"])) == 50


def test_a_drive_keeps_its_sun_but_its_fog_drifts():
    condition = ConditionParams.from_config("c", {"fog_beta": [0.01, 0.02],
                                                  "sun_intensity": [2.0, 3.0]})
    weather = sample_drive_weather(condition, n=200, rng=stream_rng(0, "d"), jitter=0.2)
    assert np.unique(weather.values["sun_azimuth_deg"]).size == 1
    assert np.unique(weather.values["sun_elevation_deg"]).size == 1
    beta = weather.values["fog_beta"]
    assert beta.std() > 0 and (beta >= 0.01).all() and (beta <= 0.02).all()
    assert np.abs(np.diff(beta)).max() < 0.2 * 0.01  # smooth, not frame-to-frame noise
    assert (np.linalg.norm(weather.sun_direction(), axis=1) == pytest.approx(1.0))


def test_camera_quantises_to_uint8_and_rain_adds_streaks():
    radiance = np.full((1, 32, 32, 3), 0.2, np.float32)
    clear = camera_image(radiance, fixed_weather(noise_std=0.0), supersample=2)
    rain = camera_image(radiance, fixed_weather(noise_std=0.0, rain_density=40.0, rain_alpha=0.5),
                        supersample=2)
    assert clear.dtype == np.uint8 and clear.shape == (1, 16, 16, 3)
    assert np.unique(clear).size == 1
    assert rain.max() > clear.max()
