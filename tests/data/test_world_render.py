"""The heightmap renderer: geometry is right, deterministic, and independent of the weather."""

from __future__ import annotations

import dataclasses
import math

import numba
import numpy as np
import pytest

from cmal_lcd.data.world import (DataConfig, HeightmapRenderer, World, build_world, make_renderer,
                                 make_world_renderer, plan_drive, render_group)
from cmal_lcd.data.world import materials as M


def flat_world(config: DataConfig, *, wall_x: float | None = None, wall_height: float = 10.0,
               n: int = 128, cell: float = 0.5) -> World:
    """A flat, empty world (ground at 0 m), optionally with a wall across ``x = wall_x``."""
    spec = dataclasses.replace(config.world, size_m=n * cell, cell_m=cell)
    ground = np.zeros((n, n), np.float32)
    height = ground.copy()
    material = np.full((n, n), M.GRASS, np.uint8)
    if wall_x is not None:
        ix = int(wall_x / cell)
        height[:, ix] = wall_height
        material[:, ix] = M.BUILDING
    return World(spec=spec, height=height, ground=ground, material=material,
                 albedo=np.full((n, n, 3), 80, np.uint8), style=np.zeros((n, n), np.uint8),
                 road_lateral=np.full((n, n), 100.0, np.float32),
                 road_s=np.zeros((n, n), np.float32), puddle=np.zeros((n, n), np.uint8),
                 canopy_lo=np.full((n, n), np.inf, np.float32),
                 canopy_hi=np.full((n, n), -np.inf, np.float32),
                 sprites=np.zeros((0, len(M.SPRITE_FIELDS)), np.float32),
                 palette=M.palette(), skyline=np.zeros(360, np.float32), roads={},
                 train_roads=(), routes=())


def test_depth_is_the_distance_to_the_ground_and_to_a_wall(tiny):
    _, config, _ = tiny
    camera = dataclasses.replace(config.camera, pitch_deg=0.0, height_m=1.8)
    world = flat_world(config, wall_x=30.0)
    renderer = HeightmapRenderer(world, camera, image_size=(32, 32))
    gbuf = renderer.render(np.array([10.1]), np.array([32.3]), np.array([0.0]))
    f = renderer.focal
    c = 16  # the ray of column 16 points slightly right of +x
    xc = (c + 0.5 - 16) / f
    # bottom row: the ground, at forward distance 1.8 / |k|
    k = (renderer.horizon - 31.5) / f
    expected = 1.8 / -k * math.sqrt(1 + xc * xc + k * k)
    assert gbuf.depth[0, 31, c] == pytest.approx(expected, rel=0.02)
    assert gbuf.material[0, 31, c] == M.GRASS
    # the row just above the horizon: the wall at x = 30 m, 19.9 m ahead
    r = int(renderer.horizon) - 1
    k = (renderer.horizon - (r + 0.5)) / f
    assert gbuf.material[0, r, c] in (M.BUILDING, M.WINDOW)
    assert gbuf.depth[0, r, c] == pytest.approx(19.9 * math.sqrt(1 + xc * xc + k * k), rel=0.01)
    assert gbuf.normal[0, r, c].tolist() == [-1.0, 0.0, 0.0]  # the wall faces the camera
    # looking away from the wall over the flat world's edge: sky at infinity above the horizon
    back = renderer.render(np.array([10.1]), np.array([32.3]), np.array([math.pi]))
    assert np.isinf(back.depth[0, 0]).all() and (back.material[0, 0] == M.SKY).all()


def test_a_wall_casts_a_shadow_on_the_ground_behind_it(tiny):
    _, config, _ = tiny
    camera = dataclasses.replace(config.camera, pitch_deg=-20.0)
    world = flat_world(config, wall_x=30.0, wall_height=6.0)
    renderer = HeightmapRenderer(world, camera, image_size=(32, 32))
    # camera beyond the wall, looking back at it (-x); the sun is behind the wall (+x... no: -x)
    sun = np.array([[-math.cos(math.radians(30)), 0.0, math.sin(math.radians(30))]])
    gbuf = renderer.render(np.array([45.1]), np.array([32.3]), np.array([math.pi]),
                           sun_direction=sun)
    ground = gbuf.material[0] == M.GRASS
    distance = gbuf.depth[0]
    # ground between camera (x = 45.1) and the wall (x = 30): lit when farther from the wall
    # than 6 m / tan(30 deg) = 10.4 m, i.e. closer to the camera than ~4.7 m
    near = ground & (distance < 4.0)
    shaded = ground & (distance > 7.0) & (distance < 13.0)
    assert near.any() and shaded.any()
    assert (gbuf.sun_visibility[0][near] == 1.0).all()
    assert (gbuf.sun_visibility[0][shaded] == 0.0).all()


def render_drive(config, world, condition: str, *, seed: int = 0) -> np.ndarray:
    renderer = make_renderer(config.renderer, world, config.camera,
                             image_size=tuple(v * config.supersample for v in config.image_size))
    group = plan_drive(config, world, "route1", condition, seed=seed)
    return render_group(renderer, group, supersample=config.supersample,
                        sky_distance_m=config.camera.max_distance_m)


def test_same_seed_and_params_give_identical_bytes(tiny):
    _, config, world = tiny
    first = render_drive(config, world, "sunny")
    rebuilt = build_world(config, seed=0)
    again = render_drive(config, rebuilt, "sunny")
    assert first.dtype == np.uint8 and first.shape[1:] == (16, 16, 3)
    assert first.tobytes() == again.tobytes()
    other_seed = build_world(config, seed=1)
    assert render_drive(config, other_seed, "sunny", seed=1).tobytes() != first.tobytes()


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs 2 numba threads")
def test_thread_count_does_not_change_the_frames(tiny):
    _, config, world = tiny
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = render_drive(config, world, "rainy")
        numba.set_num_threads(2)
        two = render_drive(config, world, "rainy")
    finally:
        numba.set_num_threads(before)
    assert one.tobytes() == two.tobytes()


def test_weather_changes_appearance_but_not_geometry(tiny):
    _, config, world = tiny
    renderer = make_renderer("heightmap", world, config.camera, image_size=(16, 16))
    groups = {c: plan_drive(config, world, "route1", c, seed=0) for c in config.conditions}
    n = min(len(g) for g in groups.values())
    sunny = groups["sunny"]
    poses = dataclasses.replace(sunny.poses, **{f: getattr(sunny.poses, f)[:n] for f in
                                                ("x", "y", "heading", "s", "time")})
    lit = renderer.render(poses.x, poses.y, poses.heading,
                          sun_direction=sunny.weather.sun_direction()[:n])
    overcast = renderer.render(poses.x, poses.y, poses.heading)
    for field in ("depth", "material", "normal", "albedo", "view", "puddle"):
        assert np.array_equal(getattr(lit, field), getattr(overcast, field)), field
    assert (lit.sun_visibility < 1).any() and (overcast.sun_visibility == 1).all()
    images = {}
    for condition, group in groups.items():
        group = dataclasses.replace(group, poses=poses, weather=group.weather.subset(slice(0, n)))
        images[condition] = render_group(renderer, group, supersample=1,
                                         sky_distance_m=config.camera.max_distance_m)
    for a in images:
        for b in images:
            if a != b:
                assert np.abs(images[a].astype(int) - images[b].astype(int)).mean() > 5, (a, b)


def test_the_supersampled_renderer_has_the_requested_size(tiny):
    _, config, _ = tiny
    config = dataclasses.replace(config, supersample=2)
    world, renderer = make_world_renderer(config, seed=0)
    assert renderer.image_size == (32, 32)
    assert render_drive(config, world, "foggy").shape[1:] == (16, 16, 3)


def test_unknown_renderer_is_rejected(tiny):
    _, config, world = tiny
    with pytest.raises(ValueError, match="name"):
        make_renderer("raytracer", world, config.camera, image_size=(8, 8))
