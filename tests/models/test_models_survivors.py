"""Specifications the mutation run over the model losses showed missing (docs/testing.md).

Expected values come from ``torch.nn.functional.binary_cross_entropy_with_logits`` on scores
fixed here, never from the loss code under test.
"""

import pytest
import torch
import torch.nn.functional as F
from test_objective_signs import bigan, fixed_batch

from cmal_lcd.models.bigan import _score_loss


def bce(logits, target: float) -> float:
    return F.binary_cross_entropy_with_logits(logits, torch.full_like(logits, target)).item()


@pytest.mark.parametrize("real", [True, False])
def test_bigans_score_loss_is_the_sum_over_its_columns(real):
    """Joint, frame and code scores each count once (kills a loop that counts column 0
    twice)."""
    scores = torch.tensor([[0.5, -1.0, 2.0], [1.5, 0.25, -0.75]])
    expected = sum(bce(scores[:, k], float(real)) for k in range(3))
    assert _score_loss(scores, real=real).item() == pytest.approx(expected, rel=1e-6)


def test_bigans_generator_unary_term_is_the_frame_score_of_generated_frames():
    """With unary scores, ``G/adv_x`` is the frame-only score (column 1) of the generator's
    pairs and ``E/adv_z`` the code-only score (column 2) of the encoder's pairs: D is stubbed
    with constant columns that still depend on the inputs, so each term is identifiable."""
    model = bigan(unary_scores=True)
    batch = fixed_batch(model)
    columns = {"enc": (0.3, -0.4, 1.1), "gen": (-0.2, 0.9, -1.3)}

    def scores(x, z):
        kind = "gen" if z is batch.noise else "enc"
        tie = 0.0 * (x.mean(dim=(1, 2, 3)) + z.mean(dim=1))  # keeps the graph to E and G
        return torch.stack([tie + v for v in columns[kind]], dim=1)

    model.discriminator.scores = scores
    opt = model.make_optimizers()["G"]
    logs = model.g_step(batch.x, model.encoder(batch.x), model.generator(batch.noise),
                        batch.noise, opt)
    gen, enc = torch.tensor([columns["gen"]] * 2), torch.tensor([columns["enc"]] * 2)
    assert logs["G/adv_x"] == pytest.approx(bce(gen[:, 1], 1.0), rel=1e-6)
    assert logs["E/adv_z"] == pytest.approx(bce(enc[:, 2], 0.0), rel=1e-6)
    assert logs["G/adv"] == pytest.approx(bce(gen[:, 0], 1.0), rel=1e-6)
    assert logs["E/adv"] == pytest.approx(bce(enc[:, 0], 0.0), rel=1e-6)


def test_extra_code_critic_steps_see_fresh_prior_draws_at_the_prior_scale():
    """The first critic update uses the batch's prior draws; each extra one
    (``code_critic_steps > 1``, 5 in the default config) a fresh draw of the same scale, so
    ``D_z`` does not see one noise batch five times (kills ``step == 0`` mutated to always or
    never take the batch's draws)."""
    from test_cmal_code_prior import make_batch, make_model

    model = make_model(code_critic_steps=3, code_critic_hidden=16,
                       loss_weights={"prior": 1.0, "adversary": 1.0})
    batch = make_batch(model, 8)
    seen = []
    dz_step = model.dz_step

    def spy(critic_batch, code, optimizer):
        seen.append(critic_batch.noise.clone())
        return dz_step(critic_batch, code, optimizer)

    model.dz_step = spy
    torch.manual_seed(123)  # the global stream the extra draws come from (not the batch's)
    model.training_step(batch, model.make_optimizers())
    assert len(seen) == 3
    assert torch.equal(seen[0], batch.noise)
    assert not torch.equal(seen[1], batch.noise) and not torch.equal(seen[2], seen[1])
    for noise in seen[1:]:
        assert noise.shape == batch.noise.shape
        assert float(noise.std()) == pytest.approx(model.prior_std, rel=0.1)
