"""Splits of the weather world: disjoint regions, drives with wander and unvisited stretches."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from cmal_lcd.data.world import frame_table, plan_dataset, plan_drive, plan_train
from cmal_lcd.data.world.config import LoopSpec
from cmal_lcd.data.world.dataset import loop_entries
from cmal_lcd.evaluation import ground_truth_from_poses


def inside(frames, box) -> np.ndarray:
    x0, x1, y0, y1 = box
    return ((frames["x"] >= x0) & (frames["x"] <= x1) & (frames["y"] >= y0)
            & (frames["y"] <= y1)).to_numpy()


def test_train_and_test_regions_are_disjoint_and_hold_their_frames(tiny):
    _, config, world = tiny
    frames = frame_table(plan_dataset(config, world, seed=0))
    train_box, test_box = world.region_box("train"), world.region_box("test")
    assert train_box[1] < test_box[0]
    train = frames[frames["split"] == "train"]
    test = frames[frames["split"] == "test"]
    assert len(train) == config.train_per_condition * len(config.conditions)
    assert inside(train, train_box).all()
    assert inside(test, test_box).all()
    assert train["route"].eq("").all() and train["s"].isna().all()
    assert (frames["frame"].to_numpy() == np.arange(len(frames))).all()


def test_each_route_is_driven_once_under_every_condition_plus_the_loops_lap_2(tiny):
    _, config, world = tiny
    frames = frame_table(plan_dataset(config, world, seed=0))
    test = frames[frames["split"] == "test"]
    control = config.test.loops.control
    assert control == "sunny"
    assert sorted(set(test["drive"])) == sorted(
        [f"{r}/{c}" for r in config.test.routes for c in config.conditions]
        + [f"{r}/{control}_lap2" for r in config.test.routes])
    for _, drive in test.groupby("drive"):
        assert (np.diff(drive["time"]) > 0).all() and (np.diff(drive["s"]) > 0).all()
    # the lap-2 drive follows its route's drives: every route's test rows stay contiguous
    for route in config.test.routes:
        rows = test.index[test["route"] == route].to_numpy()
        assert (np.diff(rows) == 1).all()


def test_the_control_lap_2_drives_the_same_window_with_its_own_wander_and_weather(tiny):
    _, config, world = tiny
    lap1 = plan_drive(config, world, "route1", "sunny", seed=0)
    lap2 = plan_drive(config, world, "route1", "sunny", seed=0, repeat="lap2")
    assert lap2.drive == "route1/sunny_lap2" and lap2.split == "test"
    assert abs(lap2.poses.s[0] - lap1.poses.s[0]) < 2 * config.test.frame_spacing_m
    assert not np.allclose(lap1.poses.x[:len(lap2)], lap2.poses.x[:len(lap1)])


def test_loop_entries_list_the_weather_changes_then_the_control_per_route(tiny):
    _, config, world = tiny
    loops = loop_entries(config)
    assert loops[:3] == [["route1", "route1/sunny", "route1/rainy", "sunny-rainy"],
                         ["route1", "route1/sunny", "route1/foggy", "sunny-foggy"],
                         ["route1", "route1/sunny", "route1/sunny_lap2", "sunny-sunny"]]
    assert len(loops) == 3 * len(config.test.routes)
    none = dataclasses.replace(config, test=dataclasses.replace(config.test,
                                                                loops=LoopSpec()))
    assert loop_entries(none) == []
    without = frame_table(plan_dataset(none, world, seed=0))
    assert not without["drive"].str.endswith("_lap2").any()
    assert len(without) < len(frame_table(plan_dataset(config, world, seed=0)))


def test_a_validation_route_is_driven_like_a_test_route_but_is_its_own_split(tiny):
    _, config, world = tiny
    frames = frame_table(plan_dataset(config, world, seed=0))
    val = frames[frames["split"] == "val"]
    assert list(config.test.validation_routes) == ["val"]
    assert sorted(set(val["drive"])) == sorted(f"val/{c}" for c in config.conditions)
    assert not set(val["route"]) & set(config.test.routes)
    assert inside(val, world.region_box("test")).all()
    test = frames[frames["split"] == "test"]
    assert len(frame_table(plan_dataset(
        dataclasses.replace(config, test=dataclasses.replace(config.test,
                                                             validation_routes={})),
        world, seed=0)).query("split == 'test'")) == len(test)


def test_query_drives_have_a_stretch_their_reference_never_visits(tiny):
    cfg, config, world = tiny
    for route in config.test.routes:
        for ref, query in config.test.pairs:
            a = plan_drive(config, world, route, ref, seed=0).poses
            b = plan_drive(config, world, route, query, seed=0).poses
            truth = ground_truth_from_poses(np.c_[a.x, a.y], np.c_[b.x, b.y],
                                            max_distance=cfg.matching.pose_tolerance)
            assert (truth < 0).mean() >= 0.15 - 0.05, (route, ref, query)  # 15% of arc length
            assert (truth >= 0).mean() > 0.5


def test_drives_wander_smoothly_within_the_configured_ranges(tiny):
    _, config, world = tiny
    a = plan_drive(config, world, "route1", "foggy", seed=0).poses
    b = plan_drive(config, world, "route1", "rainy", seed=0).poses
    spacing = np.diff(a.s) / config.test.frame_spacing_m
    lo, hi = config.test.wander.speed
    assert (spacing >= lo - 1e-9).all() and (spacing <= hi + 1e-9).all()
    road = world.roads["route1"]
    xy, tangent, _ = road.at(a.s)
    left = -tangent[:, 1] * (a.x - xy[:, 0]) + tangent[:, 0] * (a.y - xy[:, 1])
    lane = config.world.lane_width_m / 2
    assert np.abs(left + lane).max() <= config.test.wander.lateral_m + 1e-6  # right-hand lane
    assert np.abs(left + lane).max() > 0.05  # wanders: not an exactly retraced path
    heading = np.arctan2(tangent[:, 1], tangent[:, 0])
    dh = np.angle(np.exp(1j * (a.heading - heading)))
    assert np.abs(np.rad2deg(dh)).max() <= config.test.wander.heading_deg + 1e-6
    assert not np.allclose(a.x[:10], b.x[:10])


def test_growing_the_training_set_changes_no_other_frame(tiny):
    _, config, world = tiny
    small = plan_train(config, world, seed=0)
    large = plan_train(dataclasses.replace(config, train_per_condition=5), world, seed=0)
    for a, b in zip(small, large):
        assert np.array_equal(a.poses.x, b.poses.x[:3])
        assert np.array_equal(a.weather.noise_seed, b.weather.noise_seed[:3])
    drive = plan_drive(dataclasses.replace(config, train_per_condition=5), world, "route2",
                       "sunny", seed=0)
    assert np.array_equal(drive.poses.x, plan_drive(config, world, "route2", "sunny",
                                                    seed=0).poses.x)


@pytest.mark.parametrize("paired", [False, True])
def test_training_poses_are_unpaired_unless_asked(tiny, paired):
    _, config, world = tiny
    config = dataclasses.replace(config, train=dataclasses.replace(config.train, paired=paired))
    groups = plan_train(config, world, seed=0)
    same = np.array_equal(groups[0].poses.x, groups[1].poses.x)
    assert same == paired
    assert not np.array_equal(groups[0].weather.noise_seed, groups[1].weather.noise_seed)
