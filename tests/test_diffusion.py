"""Tests of the noise schedule wrapper around diffusers' DDPM / DDIM schedulers."""

from __future__ import annotations

import pytest
import torch

from spade.models.cond_expert import build_cond_expert
from spade.models.diffusion import NoiseSchedule, from_model_range, to_model_range
from spade.models.uncond_expert import build_uncond_expert


def test_add_noise_matches_closed_form() -> None:
    sched = NoiseSchedule(num_train_timesteps=1000, beta_schedule="sigmoid")
    g = torch.Generator().manual_seed(0)
    x0 = torch.rand(4, 1, 8, 8, generator=g) * 2 - 1
    eps = torch.randn(4, 1, 8, 8, generator=g)
    t = torch.tensor([0, 10, 500, 999])
    abar = torch.cumprod(1 - sched.betas, 0)[t].view(-1, 1, 1, 1)
    expected = abar.sqrt() * x0 + (1 - abar).sqrt() * eps
    torch.testing.assert_close(sched.add_noise(x0, eps, t), expected)


def test_add_noise_is_differentiable_in_x0() -> None:
    sched = NoiseSchedule()
    x0 = torch.zeros(2, 1, 4, 4, requires_grad=True)
    sched.add_noise(x0, torch.randn(2, 1, 4, 4), torch.tensor([3, 700])).sum().backward()
    assert x0.grad is not None and (x0.grad > 0).all()


def test_sigmoid_schedule_is_dbc_schedule() -> None:
    sched = NoiseSchedule(num_train_timesteps=1000, beta_schedule="sigmoid", beta_start=1e-4, beta_end=0.02)
    dbc = torch.sigmoid(torch.linspace(-6, 6, 1000)) * (0.02 - 1e-4) + 1e-4
    torch.testing.assert_close(sched.betas, dbc)
    # DDIM is built from the same betas (diffusers' DDIMScheduler has no "sigmoid" option).
    torch.testing.assert_close(sched._make("ddim").alphas_cumprod, sched.alphas_cumprod)


@pytest.mark.parametrize("schedule", ["squaredcos_cap_v2", "linear", "sigmoid"])
def test_schedules_decay_to_noise(schedule: str) -> None:
    abar = NoiseSchedule(beta_schedule=schedule).alphas_cumprod
    assert abar[0] > 0.99 and abar[-1] < 0.01 and (abar[1:] <= abar[:-1]).all()


def test_bad_arguments_raise() -> None:
    with pytest.raises(ValueError, match="beta_schedule"):
        NoiseSchedule(beta_schedule="cosine")
    sched = NoiseSchedule(num_train_timesteps=100)
    with pytest.raises(ValueError, match="sampler"):
        sched.sample(lambda x, t: x, (1, 1, 4, 4), sampler="euler")
    with pytest.raises(ValueError, match=r"\[0, 99\]"):
        sched.add_noise(torch.zeros(1, 1, 2, 2), torch.zeros(1, 1, 2, 2), torch.tensor([100]))


@pytest.mark.parametrize("sampler", ["ddim", "ddpm"])
def test_seeded_sampling_is_deterministic(sampler: str) -> None:
    torch.manual_seed(0)
    model = build_cond_expert("tiny").eval()
    sched = NoiseSchedule(num_train_timesteps=100)
    cond = torch.rand(2, 3, 16, 16)
    runs = [
        sched.sample(model, (2, 1, 16, 16), torch.Generator().manual_seed(seed), sampler, 4, cond=cond)
        for seed in (7, 7, 8)
    ]
    torch.testing.assert_close(runs[0], runs[1], rtol=0, atol=0)
    assert not torch.allclose(runs[0], runs[2])


def test_ddim_sample_is_clipped_to_data_range() -> None:
    torch.manual_seed(0)
    model = build_uncond_expert("tiny").eval()
    sched = NoiseSchedule(num_train_timesteps=1000, beta_schedule="sigmoid", clip_sample=True)
    x = sched.sample(model, (2, 4, 16, 16), torch.Generator().manual_seed(0), "ddim", num_inference_steps=3)
    assert x.shape == (2, 4, 16, 16)
    assert torch.isfinite(x).all() and x.min() >= -1 and x.max() <= 1


def test_sampler_recovers_known_clean_image() -> None:
    """With an oracle noise predictor for a fixed x0, DDIM must return that x0."""
    sched = NoiseSchedule(num_train_timesteps=1000)
    target = to_model_range((torch.rand(1, 1, 8, 8, generator=torch.Generator().manual_seed(1)) > 0.5).float())
    abar = sched.alphas_cumprod

    def oracle(x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        a = abar[t].view(-1, 1, 1, 1)
        return (x - a.sqrt() * target) / (1 - a).sqrt()

    x = sched.sample(oracle, (1, 1, 8, 8), torch.Generator().manual_seed(0), "ddim", num_inference_steps=10)
    torch.testing.assert_close(x, target, atol=1e-4, rtol=0)
    assert set(from_model_range(x).round().unique().tolist()) <= {0.0, 1.0}


def test_antithetic_timesteps() -> None:
    sched = NoiseSchedule(num_train_timesteps=1000)
    t = sched.random_timesteps(8, torch.Generator().manual_seed(0))
    assert t.dtype == torch.long and t.shape == (8,)
    torch.testing.assert_close(t[:4] + t[4:], torch.full((4,), 999))
    assert sched.random_timesteps(5, antithetic=False).shape == (5,)


def test_range_mapping_round_trips() -> None:
    p = torch.tensor([0.0, 0.5, 1.0])
    torch.testing.assert_close(to_model_range(p), torch.tensor([-1.0, 0.0, 1.0]))
    torch.testing.assert_close(from_model_range(to_model_range(p)), p)


def test_config_rebuilds_schedule() -> None:
    sched = NoiseSchedule(num_train_timesteps=50, beta_schedule="linear", clip_sample=False)
    torch.testing.assert_close(NoiseSchedule(**sched.config).betas, sched.betas)


@pytest.mark.parametrize("prediction_type", ["epsilon", "sample", "v_prediction"])
def test_sampler_recovers_known_clean_image_in_every_parameterisation(prediction_type: str) -> None:
    """An oracle that outputs prediction_target(x0, eps_hat, t) for a fixed x0 makes DDIM return that x0."""
    sched = NoiseSchedule(num_train_timesteps=1000, prediction_type=prediction_type)
    target = to_model_range((torch.rand(1, 1, 8, 8, generator=torch.Generator().manual_seed(1)) > 0.5).float())
    abar = sched.alphas_cumprod

    def oracle(x: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        a = abar[t].view(-1, 1, 1, 1)
        eps = (x - a.sqrt() * target) / (1 - a).sqrt()
        return sched.prediction_target(target.expand_as(x), eps, t)

    x = sched.sample(oracle, (1, 1, 8, 8), torch.Generator().manual_seed(0), "ddim", num_inference_steps=5)
    torch.testing.assert_close(x, target, atol=1e-4, rtol=0)


def test_prediction_targets_agree_with_diffusers_and_each_other() -> None:
    """sample -> x0, epsilon -> noise, v -> diffusers' get_velocity; each error is the epsilon error times a factor."""
    x0 = torch.randn(3, 1, 4, 4, generator=torch.Generator().manual_seed(0))
    noise = torch.randn(3, 1, 4, 4, generator=torch.Generator().manual_seed(1))
    t = torch.tensor([10, 500, 900])
    eps_s = NoiseSchedule(prediction_type="epsilon")
    x0_s = NoiseSchedule(prediction_type="sample")
    v_s = NoiseSchedule(prediction_type="v_prediction")
    torch.testing.assert_close(eps_s.prediction_target(x0, noise, t), noise)
    torch.testing.assert_close(x0_s.prediction_target(x0, noise, t), x0)
    torch.testing.assert_close(v_s.prediction_target(x0, noise, t), v_s._train.get_velocity(x0, noise, t))
    # A network output o for x_t: its implied x0 estimates agree whatever the parameterisation, so the errors
    # are multiples of one another: |x0_hat - x0|^2 = (1 - abar) / abar |eps_hat - eps|^2.
    x_t = eps_s.add_noise(x0, noise, t)
    abar = eps_s.alphas_cumprod[t].view(-1, 1, 1, 1)
    eps_hat = torch.randn(x0.shape, generator=torch.Generator().manual_seed(2))
    x0_hat = (x_t - (1 - abar).sqrt() * eps_hat) / abar.sqrt()
    e_eps = eps_s.denoising_error(eps_hat, x0, noise, t)
    e_x0 = x0_s.denoising_error(x0_hat, x0, noise, t)
    torch.testing.assert_close(e_x0, e_eps * ((1 - abar) / abar).view(-1), rtol=1e-4, atol=1e-6)
    v_hat = abar.sqrt() * eps_hat - (1 - abar).sqrt() * x0_hat
    torch.testing.assert_close(v_s.denoising_error(v_hat, x0, noise, t), e_eps / abar.view(-1), rtol=1e-4, atol=1e-6)
