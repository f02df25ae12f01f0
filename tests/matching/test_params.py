"""SeqSLAMParams: Table I defaults from one place, validation, velocities and trajectory offsets."""

import math
import re

import numpy as np
import pytest
from omegaconf import OmegaConf

from cmal_lcd.matching import SeqSLAMParams, matching_defaults, sad_thumbnails, \
    trajectory_offsets, trajectory_velocities
from cmal_lcd.matching import params as params_module


@pytest.fixture(scope="module")
def seqslam_yaml(repo_root):
    return OmegaConf.to_container(OmegaConf.load(repo_root / "conf/matching/seqslam.yaml"))


def test_defaults_are_table_one():
    p = SeqSLAMParams.defaults()
    assert (p.ds, p.v_min, p.v_max, p.v_step) == (10, 0.8, 1.1, 0.1)
    assert (p.r_window, p.enhance, p.score) == (10, True, "ratio")


def test_the_library_defaults_are_the_config_file(seqslam_yaml):
    assert matching_defaults() == seqslam_yaml
    assert SeqSLAMParams.defaults() == SeqSLAMParams.from_config(seqslam_yaml)


def test_the_library_defaults_are_the_default_compositions_matching_node():
    """``match`` and ``loops`` without ``--config`` read the file, not a composition: it must
    be what composing ``conf/`` gives (nothing in ``conf/config.yaml`` may override it)."""
    from cmal_lcd.config import compose

    assert matching_defaults() == OmegaConf.to_container(compose().matching)


def test_the_library_reads_its_defaults_from_the_config_file_only(monkeypatch):
    # no copy in Python: another file gives other defaults (SeqSLAMParams, sad_thumbnails)
    edited = {**matching_defaults(), "ds": 3, "sad": {"width": 16, "height": 8, "patch": 4}}
    monkeypatch.setattr(params_module, "_read_matching_defaults", lambda: edited)
    assert SeqSLAMParams.defaults().ds == 3 and SeqSLAMParams.defaults(ds=5).ds == 5
    images = np.zeros((2, 40, 60, 3), dtype=np.uint8)
    assert sad_thumbnails(images).shape == (2, 16 * 8)
    assert sad_thumbnails(images, width=8).shape == (2, 8 * 8)


def test_a_bad_config_file_is_refused_naming_the_file_and_the_key(tmp_path, monkeypatch,
                                                                   seqslam_yaml):
    import yaml

    from cmal_lcd import checkout

    (tmp_path / "matching").mkdir()
    (tmp_path / "matching/seqslam.yaml").write_text(yaml.safe_dump({**seqslam_yaml,
                                                                     "d_thresh": 20.7}))
    monkeypatch.setattr(checkout, "CONF_DIR", tmp_path)
    params_module._read_matching_defaults.cache_clear()
    try:
        with pytest.raises(ValueError, match=r"seqslam\.yaml: matching\.d_thresh"):
            matching_defaults()
    finally:
        params_module._read_matching_defaults.cache_clear()


def test_from_config_ignores_keys_that_are_not_fields():
    p = SeqSLAMParams.from_config({**matching_defaults(), "ds": 5})
    assert p.ds == 5 and p.v_max == 1.1


@pytest.mark.parametrize("kwargs, name", [
    ({"ds": 0}, "ds"), ({"ds": 2.5}, "ds"), ({"v_min": 0.0}, "v_min"),
    ({"v_min": 1.2, "v_max": 1.1}, "v_min"), ({"v_step": 0.0}, "v_step"),
    ({"v_step": -0.1}, "v_step"), ({"r_window": -1}, "r_window"), ({"r_window": 1}, "r_window"),
    ({"score": "max"}, "score"), ({"v_max": math.nan}, "v_max"), ({"enhance": "yes"}, "enhance"),
])
def test_invalid_values_raise_naming_the_parameter(kwargs, name):
    with pytest.raises(ValueError, match=name):
        SeqSLAMParams.defaults(**kwargs)


def test_one_row_window_is_allowed_without_enhancement():
    assert SeqSLAMParams.defaults(r_window=1, enhance=False).enhancement_window == 0


def test_table_one_velocities_include_both_ends():
    np.testing.assert_array_equal(SeqSLAMParams.defaults().velocities(), [0.8, 0.9, 1.0, 1.1])


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
    offsets = SeqSLAMParams.defaults(ds=7, v_min=0.3, v_max=1.7, v_step=0.2).offsets()
    assert (offsets[:, 0] == 0).all()
    assert (np.diff(offsets, axis=1) >= 0).all()


def test_the_constructor_reads_no_file_and_needs_every_field(monkeypatch):
    """Defaults are asked for by name (``defaults()``), never filled in by the constructor."""
    monkeypatch.setattr(params_module, "_read_matching_defaults", lambda: pytest.fail("read"))
    given = dict(ds=4, v_min=0.8, v_max=1.1, v_step=0.1, r_window=6, enhance=True, score="sum")
    assert SeqSLAMParams(**given).as_dict() == given
    with pytest.raises(TypeError, match="score"):
        SeqSLAMParams(**{k: v for k, v in given.items() if k != "score"})


@pytest.mark.parametrize("override, values, message", [
    ("matching.ds=0", dict(ds=0), "ds: must be >= 1, got 0"),
    ("matching.v_max=1e300", dict(v_max=1e300), "v_max: must be <= 100.0, got 1e+300"),
    ("matching.v_step=1e-9", dict(v_step=1e-9), "v_step: 1e-09 gives more than 1000 velocities"),
    ("matching.r_window=1", dict(r_window=1), "r_window: 1 gives one-row enhancement windows"),
    ("matching.score=max", dict(score="max"), "score: must be one of ['ratio', 'sum']"),
])
def test_a_value_is_refused_by_one_rule_wherever_it_comes_from(override, values, message):
    """The composed config (``matching.``-prefixed) and a direct ``SeqSLAMParams`` give the same
    message: both are the ``matching`` schema's check (``cmal_lcd.fields.check_values``)."""
    from cmal_lcd.config import compose

    with pytest.raises(ValueError, match=re.escape(f"matching.{message}")):
        compose([override])
    with pytest.raises(ValueError, match=f"^{re.escape(message)}"):
        SeqSLAMParams.defaults(**values)


def test_numpy_scalars_are_taken_as_python_values():
    p = SeqSLAMParams.defaults(ds=np.int64(7), v_step=np.float32(0.5), enhance=np.True_)
    assert type(p.ds) is int and type(p.v_step) is float and p.enhance is True
    assert type(SeqSLAMParams.defaults(v_min=1).v_min) is float
