"""The ``compile`` switch of the training loop (issue 36 item 3): the step's modules under
``torch.compile`` give the eager losses within float tolerance, and the saved model is the
eager model's (same ``state_dict`` keys, loads without compiling)."""

import pandas as pd
import pytest
import torch
from model_helpers import CONDITIONS, tiny_config, weather_frames

from cmal_lcd.models import build_model, load_trained, train_model
from cmal_lcd.models.config import model_config
from cmal_lcd.models.training import compile_modules


def trained_log(tmp_path, name: str, backend: str | None) -> pd.DataFrame:
    images, labels = weather_frames(24)
    cfg = tiny_config(name, compile=backend, iterations=4, validate_every=0, select="last")
    out = tmp_path / (backend or "eager")
    train_model(name, cfg, images, labels, conditions=CONDITIONS, out_dir=out, seed=0,
                threads=1)
    model, _ = load_trained(out)            # an eager model reads the compiled run's weights
    assert not any("_orig_mod" in key for key in model.state_dict())
    return pd.read_csv(out / "train_log.csv")


def assert_same_losses(eager: pd.DataFrame, compiled: pd.DataFrame) -> None:
    columns = [c for c in eager.columns if c != "iteration" and eager[c].notna().any()]
    assert columns and list(compiled.columns) == list(eager.columns)
    for column in columns:
        assert compiled[column].to_numpy() == pytest.approx(eager[column].to_numpy(),
                                                            rel=1e-3, abs=1e-4), column


def test_the_spectrally_normalised_critics_stay_eager():
    model = build_model("cmal", tiny_config("cmal"), image_size=16, n_conditions=3, seed=0)
    compiled = compile_modules(model, "aot_eager")
    assert compiled == ["classifier", "encoder", "decoder"]   # not D, D_z (spectral norm)
    assert compile_modules(model, None) == []


def test_aot_eager_gives_the_eager_losses(tmp_path):
    torch._dynamo.reset()
    assert_same_losses(trained_log(tmp_path, "cmal", None),
                       trained_log(tmp_path, "cmal", "aot_eager"))


@pytest.mark.slow
@pytest.mark.parametrize("name", ["cmal", "bigan"])
def test_inductor_gives_the_eager_losses(tmp_path, name):
    """Minutes on a 2-core CPU: inductor generates and compiles C++ for every module."""
    torch._dynamo.reset()
    assert_same_losses(trained_log(tmp_path, name, None), trained_log(tmp_path, name, "inductor"))


def test_an_unknown_backend_is_named():
    with pytest.raises(ValueError, match=r"^models\.cmal\.compile: must be one of"):
        model_config("cmal", tiny_config("cmal", compile="tensorrt"))
