"""Learned methods: trained BiGAN/CMAL encoders from ``models/<name>/model.pt``, and the
untrained CMAL control (seeded random init, no model file)."""

from pathlib import Path

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from cmal_lcd.config import CONF_DIR
from cmal_lcd.features import build_extractor
from cmal_lcd.models import build_model, preprocess

IMAGE_SIZE = 16
CONDITIONS = ["sunny", "rainy", "foggy"]


def model_conf(name: str) -> dict:
    """The real ``conf/model/<name>.yaml``, shrunk to 16x16 frames (CMAL's loss weights
    completed by ``conf/objective/paper.yaml``, as its ``objective`` group does)."""
    conf = OmegaConf.to_container(OmegaConf.load(Path(CONF_DIR) / "model" / f"{name}.yaml"))
    if name == "cmal":
        paper = OmegaConf.load(Path(CONF_DIR) / "objective" / "paper.yaml")
        conf["loss_weights"].update(OmegaConf.to_container(paper))
    conf["image_size"] = IMAGE_SIZE
    return conf


def untrained_conf(seed: int = 0) -> dict:
    return {"batch_size": 4, "model": model_conf("cmal"), "seed": seed,
            "n_conditions": len(CONDITIONS), "image_size": IMAGE_SIZE}


def write_trained_model(models_dir: Path, name: str, *, seed: int = 3, iteration: int = 7,
                        kernels: dict | None = None):
    """A ``model.pt`` in the documented format, holding a seeded (untrained) network;
    ``kernels``: the record of the kernel path that trained it (absent in older files)."""
    conf = model_conf(name)
    model = build_model(name, conf, image_size=IMAGE_SIZE, n_conditions=len(CONDITIONS), seed=seed)
    (models_dir / name).mkdir(parents=True)
    extra = {} if kernels is None else {"kernels": kernels}
    torch.save({"name": name, "config": conf, "conditions": CONDITIONS, "image_size": IMAGE_SIZE,
                "state_dict": model.state_dict(), "iteration": iteration, **extra},
               models_dir / name / "model.pt")
    return model.eval()


def codes_by_hand(model, frames: np.ndarray) -> np.ndarray:
    """The codes the paper's rule gives, spelled out from the networks (not ``model.encode``):
    CMAL ``En(x | onehot(argmax C(x)))``, BiGAN ``E(x)``. ``preprocess`` (resize, ``[-1, 1]``)
    has its own tests in ``tests/models/test_images.py``."""
    x = preprocess(frames, image_size=IMAGE_SIZE)
    with torch.inference_mode():
        if hasattr(model, "classifier"):
            decision = model.classifier(x).argmax(dim=1)
            condition = torch.nn.functional.one_hot(decision, len(CONDITIONS)).float()
            return model.encoder(x, condition).numpy()
        return model.encoder(x).numpy()


@pytest.mark.parametrize("name, label", [("cmal", "CMAL (paper objective, eqs. 9-12)"),
                                         ("bigan", "BiGAN")])
def test_trained_extractor_encodes_with_the_saved_model(tmp_path, frames, name, label):
    """The extractor loads ``model.pt`` and applies the encoding rule in batches of 4."""
    model = write_trained_model(tmp_path, name)
    extractor = build_extractor(name, conf={"batch_size": 4}, model_dir=tmp_path)
    assert extractor.label == label and extractor.metric == "sqeuclidean"
    assert (str(tmp_path / name / "model.pt") in extractor.weights
            and "iteration 7" in extractor.weights)
    codes = extractor(frames)
    expected = codes_by_hand(model, frames)
    assert codes.shape == (len(frames), 1024) and codes.dtype == np.float32
    np.testing.assert_allclose(codes, expected, rtol=1e-5, atol=1e-6)


def test_the_weights_name_the_processor_that_trained_them(tmp_path):
    """Weights differ across processor families, so every row built on trained weights says
    which processor trained them (the trained model and the untrained control's classifier)."""
    write_trained_model(tmp_path, "cmal", kernels={"cpu": "Some CPU 9000", "aten_capability": "AVX2"})
    trained = build_extractor("cmal", conf={"batch_size": 4}, model_dir=tmp_path)
    control = build_extractor("cmal_untrained", conf=untrained_conf(), model_dir=tmp_path)
    for extractor in (trained, control):
        assert "iteration 7, trained on Some CPU 9000" in extractor.weights


def test_a_model_without_a_processor_record_gives_its_iteration_only(tmp_path):
    write_trained_model(tmp_path, "bigan")
    extractor = build_extractor("bigan", conf={"batch_size": 4}, model_dir=tmp_path)
    assert extractor.weights.endswith("(iteration 7)")


def test_trained_extractor_needs_the_model_file(tmp_path):
    with pytest.raises(ValueError, match="model_dir.*train@cmal"):
        build_extractor("cmal", conf={"batch_size": 4}, model_dir=tmp_path)
    with pytest.raises(ValueError, match="model_dir"):
        build_extractor("bigan", conf={"batch_size": 4}, model_dir=None)


def test_a_model_file_of_another_method_is_rejected(tmp_path):
    write_trained_model(tmp_path, "bigan")
    (tmp_path / "cmal").mkdir()
    (tmp_path / "bigan" / "model.pt").rename(tmp_path / "cmal" / "model.pt")
    with pytest.raises(ValueError, match="'bigan' model, expected 'cmal'"):
        build_extractor("cmal", conf={"batch_size": 4}, model_dir=tmp_path)


def test_untrained_control_is_the_seeded_initial_cmal(frames):
    extractor = build_extractor("cmal_untrained", conf=untrained_conf(seed=5))
    assert extractor.label == "CMAL (untrained control)"
    assert extractor.metric == "sqeuclidean"
    assert "random" in extractor.weights and "manual_seed(5)" in extractor.weights
    reference = build_model("cmal", model_conf("cmal"), image_size=IMAGE_SIZE,
                            n_conditions=len(CONDITIONS), seed=5).eval()
    expected = codes_by_hand(reference, frames)
    codes = extractor(frames)
    assert codes.shape == (len(frames), 1024) and codes.dtype == np.float32
    np.testing.assert_allclose(codes, expected, rtol=1e-5, atol=1e-6)


def test_untrained_control_is_reproducible_and_depends_on_the_seed(frames):
    a = build_extractor("cmal_untrained", conf=untrained_conf(seed=0))(frames)
    b = build_extractor("cmal_untrained", conf=untrained_conf(seed=0))(frames)
    c = build_extractor("cmal_untrained", conf=untrained_conf(seed=1))(frames)
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)


def test_untrained_control_leaves_the_global_rng_alone():
    torch.manual_seed(123)
    expected = torch.rand(3)
    torch.manual_seed(123)
    build_extractor("cmal_untrained", conf=untrained_conf())
    np.testing.assert_array_equal(torch.rand(3).numpy(), expected.numpy())


@pytest.mark.parametrize("missing", ["model", "seed", "n_conditions", "image_size"])
def test_untrained_control_names_a_missing_setting(missing):
    conf = untrained_conf()
    del conf[missing]
    with pytest.raises(ValueError, match=missing):
        build_extractor("cmal_untrained", conf=conf)


def test_batched_codes_equal_single_frame_codes(frames):
    extractor = build_extractor("cmal_untrained", conf=untrained_conf())
    codes = extractor(frames)
    np.testing.assert_allclose(extractor(frames[4:5])[0], codes[4], rtol=1e-4, atol=1e-5)
