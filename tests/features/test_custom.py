"""A user's method is one file plus one ``extractors.<name>`` node (cmal_lcd.features.custom):
what the target may return, how the node is checked, where its stage's file dependency comes
from, and how it joins ``methods`` at composition."""

import sys
import textwrap

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from cmal_lcd.config import CONF_DIR, check_config, compose
from cmal_lcd.features import (FeatureExtractor, build_extractor, check_extractors,
                               extractor_conf, method_params)
from cmal_lcd.features.custom import check_extractor_node, method_source_file

USER_MODULE = textwrap.dedent('''
    import numpy as np
    import torch

    from cmal_lcd.features import FeatureExtractor


    def mean_colour(frames, scale=1.0):
        """frames uint8 (B, H, W, 3) -> (B, 3)"""
        return frames.reshape(len(frames), -1, 3).mean(axis=1) * scale


    class Flatten(torch.nn.Module):
        def forward(self, x):
            return x


    class RandomProjection(torch.nn.Module):
        def __init__(self, dim=4):
            super().__init__()
            self.linear = torch.nn.LazyLinear(dim)

        def forward(self, x):
            return self.linear(x.flatten(1))


    def ready_made(label="ignored"):
        return FeatureExtractor(name="x", label=label, metric="sad", weights="none",
                                backend="numpy",
                                encode=lambda f: f.reshape(len(f), -1).astype(np.float32))


    def not_an_encoder():
        return 42


    def wrong_rows(frames):
        return np.zeros((len(frames) + 1, 2))


    def broken():
        raise RuntimeError("weights file missing")
''')


@pytest.fixture
def user_module(tmp_path, monkeypatch):
    """``user_methods``: a user's file, importable (not under the checkout)."""
    (tmp_path / "user_methods.py").write_text(USER_MODULE)
    monkeypatch.syspath_prepend(str(tmp_path))
    yield tmp_path / "user_methods.py"
    sys.modules.pop("user_methods", None)  # the next test's file is another one


def conf(node, **extra):
    return {"batch_size": 2, "name": "mine", "extractor": node, "seed": 0, **extra}


def frames(n=3):
    return np.random.default_rng(0).integers(0, 256, (n, 4, 6, 3), dtype=np.uint8)


def test_a_partial_function_is_the_encoder(user_module):
    node = {"_target_": "user_methods.mean_colour", "_partial_": True, "scale": 2.0,
            "label": "Mean colour"}
    extractor = build_extractor("mine", conf=conf(node))
    images = frames(5)
    assert extractor.label == "Mean colour" and extractor.metric == "sqeuclidean"
    assert extractor.weights == "user method user_methods.mean_colour"
    np.testing.assert_allclose(extractor(images),
                               images.reshape(5, -1, 3).mean(axis=1) * 2.0, rtol=1e-6)


def test_a_torch_module_gets_rgb_in_0_1_channels_first(user_module):
    extractor = build_extractor("mine", conf=conf({"_target_": "user_methods.Flatten"}))
    images = frames()
    expected = images.transpose(0, 3, 1, 2).reshape(3, -1).astype(np.float32) / 255.0
    np.testing.assert_allclose(extractor(images), expected, rtol=1e-6)
    assert extractor.backend == "torch"


def test_image_size_resizes_before_the_encoder(user_module):
    node = {"_target_": "user_methods.Flatten", "image_size": [2, 3]}
    assert build_extractor("mine", conf=conf(node))(frames()).shape == (3, 3 * 2 * 3)


def test_random_weights_follow_the_seed_and_leave_the_callers_state(user_module):
    node = {"_target_": "user_methods.RandomProjection", "dim": 4}
    torch.manual_seed(123)
    before = torch.random.get_rng_state()
    a = build_extractor("mine", conf=conf(node, seed=5))(frames())
    assert torch.equal(torch.random.get_rng_state(), before)
    b = build_extractor("mine", conf=conf(node, seed=5))(frames())
    c = build_extractor("mine", conf=conf(node, seed=6))(frames())
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)


def test_a_ready_made_extractor_keeps_its_metric_and_takes_the_name(user_module):
    extractor = build_extractor("mine", conf=conf({"_target_": "user_methods.ready_made",
                                                   "label": "Mine"}))
    assert (extractor.name, extractor.label, extractor.metric) == ("mine", "Mine", "sad")


@pytest.mark.parametrize("target, message", [
    ("user_methods.not_an_encoder", r"extractors\.mine\._target_: returned int"),
    ("user_methods.broken", r"extractors\.mine\._target_: .*weights file missing"),
    ("user_methods.nothing_here", r"extractors\.mine\._target_: .*nothing_here"),
])
def test_a_target_that_makes_no_encoder_is_one_line_naming_the_node(user_module, target,
                                                                    message):
    with pytest.raises(ValueError, match=message) as err:
        build_extractor("mine", conf=conf({"_target_": target}))
    assert "\n" not in str(err.value)


def test_an_encoder_with_the_wrong_row_count_is_refused(user_module):
    extractor = build_extractor("mine", conf=conf({"_target_": "user_methods.wrong_rows",
                                                   "_partial_": True}))
    with pytest.raises(ValueError, match=r"extractors\.mine: .*shape \(3, 2\) for 2 frames"):
        extractor(frames())


@pytest.mark.parametrize("node, key", [
    ({}, "_target_"),
    ({"_target_": "nodots"}, "_target_"),
    ({"_target_": "m.f", "metric": "cosine"}, "metric"),
    ({"_target_": "m.f", "batch_size": 0}, "batch_size"),
    ({"_target_": "m.f", "image_size": [32]}, "image_size"),
    ({"_target_": "m.f", "label": 3}, "label"),
])
def test_node_errors_name_the_key(node, key):
    with pytest.raises(ValueError, match=rf"^extractors\.mine\.{key}: "):
        check_extractor_node("mine", node)


METHOD = {"_target_": "cmal_lcd.features.Method", "build": "m.f", "model": "m"}


@pytest.mark.parametrize("node, key", [
    ({"_target_": "cmal_lcd.features.Method", "model": "m"}, "build"),
    ({**METHOD, "build": "nodots"}, "build"),
    ({**METHOD, "choses": "m.g"}, "choses"),
    ({**METHOD, "trained": "yes"}, "trained"),
    ({**METHOD, "params": "matching"}, "params"),
    ({**METHOD, "model": None}, ""),
])
def test_method_node_errors_name_the_key(node, key):
    """A node declaring a Method (as the built-in ones are) is checked key by key."""
    where = rf"extractors\.mine\.{key}: " if key else r"extractors\.mine: .*`model`"
    with pytest.raises(ValueError, match="^" + where):
        check_extractors({"mine": node})


def test_the_built_in_nodes_are_method_nodes_that_pass_the_same_check():
    from cmal_lcd.features import METHOD_TARGET, built_in_nodes

    nodes = built_in_nodes()
    assert {node["_target_"] for node in nodes.values()} == {METHOD_TARGET}
    check_extractors(nodes)


def test_the_stage_depends_on_the_module_file(tmp_path, user_module):
    (tmp_path / "repo" / "src" / "pkg").mkdir(parents=True)
    (tmp_path / "repo" / "src" / "pkg" / "__init__.py").write_text("")
    (tmp_path / "repo" / "src" / "pkg" / "netvlad.py").write_text("raise SystemExit\n")
    (tmp_path / "repo" / "src" / "single.py").write_text("raise SystemExit\n")
    repo = tmp_path / "repo"
    # under the checkout's src/: found by path, never imported
    assert method_source_file("pkg.netvlad.NetVLAD", root=repo) == "src/pkg/netvlad.py"
    assert method_source_file("single.build", root=repo) == "src/single.py"
    # elsewhere: through the import system, an absolute path (a DVC external dependency)
    found = method_source_file("user_methods.mean_colour", root=repo)
    assert found == str(user_module.resolve())
    with pytest.raises(ValueError, match="'nowhere.build'"):
        method_source_file("nowhere.build", root=repo)
    assert method_params("mine", {"mine": {"_target_": "single.build"}}) == ("extractors.mine",)


def test_an_extractor_node_joins_methods_and_gets_its_stage_inputs(user_module):
    cfg = compose(["+extractors.mine._target_=user_methods.mean_colour",
                   "+extractors.mine._partial_=true", "+extractors.mine.label=Mine"])
    assert list(cfg.methods)[-1] == "mine"
    assert cfg.feature_inputs.mine.file == str(user_module.resolve())
    assert list(cfg.feature_inputs.mine.params) == ["extractors.mine", *["runtime.threads"] * 2]
    extractor = build_extractor("mine", conf=extractor_conf(cfg, "mine"))
    assert isinstance(extractor, FeatureExtractor) and extractor.label == "Mine"
    # an explicit list replaces the default
    explicit = compose(["+extractors.mine._target_=user_methods.mean_colour",
                        "methods=[sad,mine]"])
    assert list(explicit.methods) == ["sad", "mine"]
    assert list(explicit.feature_inputs) == ["sad", "mine"]


def test_the_default_extractors_are_the_built_in_nodes():
    from cmal_lcd.features import built_in_nodes

    cfg = compose()
    assert OmegaConf.to_container(cfg.extractors) == built_in_nodes()
    assert "- extractors: builtin" in (CONF_DIR / "config.yaml").read_text()


def test_composition_refuses_a_method_without_a_node_or_a_module(user_module):
    with pytest.raises(ValueError, match=r"methods\[1\]: unknown feature method 'vlad'.*"
                                         r"extractors\.vlad"):
        compose(["methods=[sad,vlad]"])
    with pytest.raises(ValueError, match=r"_target_: cannot find the module of 'absent\.f'"):
        compose(["+extractors.gone._target_=absent.f"])
    with pytest.raises(ValueError, match=r"extractors\.mine\.metric"):
        compose(["+extractors.mine._target_=user_methods.mean_colour",
                 "+extractors.mine.metric=cosine"])


def test_check_config_refuses_an_unsafe_extractor_name(user_module):
    cfg = compose().copy()
    cfg.extractors = {"a b": {"_target_": "user_methods.mean_colour"}}
    with pytest.raises(ValueError, match="extractors"):
        check_config(cfg)


def test_inputs_replace_the_module_file_as_the_stage_dependency():
    cfg = compose(["+extractors.pre._target_=cmal_lcd.features.precomputed.DescriptorFolder",
                   "+extractors.pre.inputs=descriptors/netvlad"])
    assert dict(cfg.feature_inputs.pre) == {"file": "descriptors/netvlad",
                                            "params": ["extractors.pre",
                                                       *["runtime.threads"] * 2]}
