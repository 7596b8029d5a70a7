"""The diffusion margin: zero for the demonstration itself, positive for worse paths, gradients only to the student."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from spade.training.guidance import DiffusionMargin, GuidanceConfig, sample_timesteps


class TinyDenoiser(nn.Module):
    """A small conditional eps-predictor, enough to carry gradients."""

    def __init__(self, channels: int = 1, cond: int = 3) -> None:
        super().__init__()
        self.conv = nn.Conv2d(channels + cond, channels, 3, padding=1)
        self.cond = cond

    def forward(self, x, t, c=None):
        c = c if c is not None else torch.zeros(x.shape[0], self.cond, *x.shape[2:])
        return self.conv(torch.cat([x, c], 1)) * (1 + t.float().view(-1, 1, 1, 1) / 1000)


def _add_noise(x0, noise, t):
    abar = (1 - t.float() / 1000).view(-1, 1, 1, 1)
    return abar.sqrt() * x0 + (1 - abar).sqrt() * noise


def _batch(b=4, s=8):
    g = torch.Generator().manual_seed(0)
    state = torch.rand(b, 3, s, s, generator=g)
    target = (torch.rand(b, 1, s, s, generator=g) > 0.7).float()
    return state, target


@pytest.mark.parametrize("clip", ["sample", "batch"])
def test_margin_is_zero_for_the_demonstration(clip: str) -> None:
    state, target = _batch()
    margin = DiffusionMargin(TinyDenoiser(), _add_noise, 1000, True, GuidanceConfig(clip=clip, num_noise=2))
    loss, active = margin(target.clone(), target, state, generator=torch.Generator().manual_seed(3))
    assert loss.item() == 0.0 and active.item() == 0.0


def test_gradients_reach_the_student_but_never_the_expert() -> None:
    state, target = _batch()
    expert = TinyDenoiser()
    before = {k: v.clone() for k, v in expert.state_dict().items()}
    margin = DiffusionMargin(expert, _add_noise, 1000, True, GuidanceConfig())
    logits = torch.zeros_like(target, requires_grad=True)
    loss, _ = margin(torch.sigmoid(logits), target, state, generator=torch.Generator().manual_seed(1))
    loss.backward()
    assert loss.item() > 0
    assert logits.grad is not None and logits.grad.abs().sum() > 0
    assert all(p.grad is None for p in expert.parameters())
    assert all(torch.equal(before[k], v) for k, v in expert.state_dict().items())
    assert not expert.training


def test_unconditional_margin_uses_the_four_channel_stack() -> None:
    state, target = _batch()
    expert = TinyDenoiser(channels=4, cond=0)
    margin = DiffusionMargin(expert, _add_noise, 1000, False, GuidanceConfig(clip="batch"))
    loss, _ = margin(torch.full_like(target, 0.5), target, state, generator=torch.Generator().manual_seed(0))
    assert torch.isfinite(loss)


def test_antithetic_timesteps_pair_up() -> None:
    t = sample_timesteps(8, 0, 1000, True, torch.device("cpu"), torch.Generator().manual_seed(0))
    assert torch.equal(t[:4] + t[4:], torch.full((4,), 999))
    t = sample_timesteps(5, 100, 200, True, torch.device("cpu"))
    assert t.min() >= 100 and t.max() < 200 and len(t) == 5


@pytest.mark.parametrize("bad", [dict(weight=-1.0), dict(clip="mean"), dict(num_noise=0), dict(t_min=5, t_max=5)])
def test_bad_guidance_options_are_refused(bad: dict) -> None:
    with pytest.raises(ValueError):
        GuidanceConfig(**bad)
