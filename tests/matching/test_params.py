"""SeqSLAMParams: Table I defaults from one place, validation, velocities and trajectory offsets."""

import inspect
import math

import numpy as np
import pytest
from omegaconf import OmegaConf

from cmal_lcd.matching import SeqSLAMParams, sad_thumbnails, trajectory_offsets, \
    trajectory_velocities


@pytest.fixture(scope="module")
def seqslam_yaml(repo_root):
    return OmegaConf.to_container(OmegaConf.load(repo_root / "conf/matching/seqslam.yaml"))


def test_defaults_are_table_one():
    p = SeqSLAMParams()
    assert (p.ds, p.v_min, p.v_max, p.v_step) == (10, 0.8, 1.1, 0.1)
    assert (p.r_window, p.enhance, p.score) == (10, True, "ratio")


def test_defaults_equal_the_config_file(seqslam_yaml):
    assert SeqSLAMParams() == SeqSLAMParams.from_config(seqslam_yaml)
    for field in ("ds", "v_min", "v_max", "v_step", "r_window", "enhance", "score"):
        assert getattr(SeqSLAMParams(), field) == seqslam_yaml[field], field


def test_sad_thumbnail_defaults_equal_the_config_file(seqslam_yaml):
    defaults = {k: v.default for k, v in inspect.signature(sad_thumbnails).parameters.items()
                if v.kind is inspect.Parameter.KEYWORD_ONLY}
    assert defaults == seqslam_yaml["sad"]


def test_from_config_ignores_keys_that_are_not_fields():
    p = SeqSLAMParams.from_config({"ds": 5, "d_thresh": 20, "sad": {"width": 64}})
    assert p.ds == 5 and p.v_max == 1.1


@pytest.mark.parametrize("kwargs, name", [
    ({"ds": 0}, "ds"), ({"ds": 2.5}, "ds"), ({"v_min": 0.0}, "v_min"),
    ({"v_min": 1.2, "v_max": 1.1}, "v_min"), ({"v_step": 0.0}, "v_step"),
    ({"v_step": -0.1}, "v_step"), ({"r_window": -1}, "r_window"), ({"r_window": 1}, "r_window"),
    ({"score": "max"}, "score"), ({"v_max": math.nan}, "v_max"), ({"enhance": "yes"}, "enhance"),
])
def test_invalid_values_raise_naming_the_parameter(kwargs, name):
    with pytest.raises(ValueError, match=name):
        SeqSLAMParams(**kwargs)


def test_one_row_window_is_allowed_without_enhancement():
    assert SeqSLAMParams(r_window=1, enhance=False).enhancement_window == 0


def test_table_one_velocities_include_both_ends():
    np.testing.assert_array_equal(SeqSLAMParams().velocities(), [0.8, 0.9, 1.0, 1.1])


def test_velocities_do_not_drift_past_v_max():
    # naive accumulation gives 0.8 + 0.1 + 0.1 + 0.1 = 1.1000000000000003 > 1.1
    assert trajectory_velocities(v_min=0.8, v_max=1.1, v_step=0.1)[-1] == 1.1
    assert list(trajectory_velocities(v_min=1.0, v_max=1.0, v_step=0.5)) == [1.0]


def test_offsets_are_floor_of_v_times_j_computed_exactly():
    almost_one = 0.1 + 3 * 0.3  # 0.9999999999999999: v * j falls just below every integer j
    assert math.floor(almost_one * 10) == 9
    offsets = trajectory_offsets(ds=10, velocities=np.array([0.8, 1.0, almost_one]))
    assert offsets.shape == (3, 11) and offsets.dtype == np.int64
    np.testing.assert_array_equal(offsets[1], np.arange(11))
    np.testing.assert_array_equal(offsets[2], np.arange(11))
    np.testing.assert_array_equal(offsets[0], [0, 0, 1, 2, 3, 4, 4, 5, 6, 7, 8])


def test_offsets_start_at_zero_and_never_decrease():
    offsets = SeqSLAMParams(ds=7, v_min=0.3, v_max=1.7, v_step=0.2).offsets()
    assert (offsets[:, 0] == 0).all()
    assert (np.diff(offsets, axis=1) >= 0).all()
