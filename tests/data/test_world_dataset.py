"""Splits of the weather world: disjoint regions, drives with wander and unvisited stretches."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from cmal_lcd.data.world import frame_table, plan_dataset, plan_drive, plan_train
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


def test_each_route_is_driven_once_under_every_condition(tiny):
    _, config, world = tiny
    frames = frame_table(plan_dataset(config, world, seed=0))
    test = frames[frames["split"] == "test"]
    assert sorted(set(test["drive"])) == sorted(f"{r}/{c}" for r in config.test.routes
                                                for c in config.conditions)
    for _, drive in test.groupby("drive"):
        assert (np.diff(drive["time"]) > 0).all() and (np.diff(drive["s"]) > 0).all()


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
