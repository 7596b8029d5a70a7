"""Classifier-free guidance for the conditional expert (a lever of the teacher): condition dropout in training, the
guided mix at sampling, an expert fine-tuned from another's weights, and the options that refuse what cannot work."""

from __future__ import annotations

import lightning
import pytest
import torch

from spade.models.modelfile import checkpoint_entry
from spade.training.expert_module import ExpertModule, guided, null_condition
from spade.training.module_options import ExpertOptions
from spade.utils.errors import ConfigError

METRICS = {"fid": False, "planner": False}


def _expert(**kwargs) -> ExpertModule:
    torch.manual_seed(0)
    return ExpertModule(conditional=True, preset="tiny", num_train_timesteps=50, num_inference_steps=4,
                        metrics=METRICS, **kwargs)


def _batch(n: int = 4, size: int = 16) -> dict:
    gen = torch.Generator().manual_seed(1)
    state = (torch.rand(n, 3, size, size, generator=gen) > 0.5).float()
    path = (torch.rand(n, 1, size, size, generator=gen) > 0.8).float()
    return {"state": state, "path": path}


class _Recorder(torch.nn.Module):
    """A stand-in denoiser: returns a function of its condition, and records the conditions it saw."""

    def __init__(self) -> None:
        super().__init__()
        self.seen: list[torch.Tensor] = []

    def forward(self, x: torch.Tensor, t: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        self.seen.append(cond.clone())
        return x * 0 + cond.mean(dim=1, keepdim=True)


def test_guided_mixes_the_conditional_and_unconditional_outputs_in_one_call() -> None:
    net, x, t = _Recorder(), torch.randn(2, 1, 4, 4), torch.tensor([3, 7])
    cond = torch.ones(2, 3, 4, 4)  # conditional output 1, unconditional (null condition: zeros) 0
    assert torch.equal(guided(net, x, t, cond, 1.0), torch.ones(2, 1, 4, 4)) and len(net.seen) == 1
    out = guided(net, x, t, cond, 3.0)  # u + 3 (c - u) = 0 + 3 (1 - 0)
    assert torch.allclose(out, torch.full((2, 1, 4, 4), 3.0)) and len(net.seen) == 2
    assert net.seen[1].shape[0] == 4 and torch.equal(net.seen[1][2:], null_condition(cond))  # one batched call
    assert torch.allclose(guided(net, x, t, cond, 0.0), torch.zeros(2, 1, 4, 4))  # the unconditional alone


def test_condition_dropout_trains_the_null_condition_on_its_share_of_instances() -> None:
    expert = _expert(cond_dropout=0.5)
    recorder = _Recorder()
    batch = _batch(n=400)
    expert.denoising_loss(recorder, batch, torch.Generator().manual_seed(0), cond_dropout=0.5)
    (cond,) = recorder.seen
    dropped = (cond.flatten(1) == 0).all(dim=1)
    assert 0.4 < dropped.float().mean().item() < 0.6  # about half the instances saw the null condition
    real = cond[~dropped]
    assert torch.equal(real, batch["state"][~dropped] * 2 - 1)  # the others their own state
    recorder.seen.clear()
    expert.denoising_loss(recorder, batch, torch.Generator().manual_seed(0))  # validation: never dropped
    assert not (recorder.seen[0].flatten(1) == 0).all(dim=1).any()


def test_sampling_at_scale_one_is_the_conditional_sampler_and_other_scales_differ() -> None:
    plain, cfg1 = _expert(), _expert(cond_dropout=0.1)
    cfg3 = _expert(cond_dropout=0.1, guidance_scale=3.0)
    state = _batch(n=2)["state"]
    a, b, c = (m.sample_paths(state, seed=5) for m in (plain, cfg1, cfg3))
    assert torch.equal(a, b)  # same weights (seeded), scale 1: the same samples
    assert not torch.allclose(a, c)


def test_the_options_refuse_guidance_an_expert_cannot_give() -> None:
    with pytest.raises(ConfigError, match="never learned: train it with model.cond_dropout=0.1"):
        ExpertOptions(preset="tiny", guidance_scale=2.0)
    with pytest.raises(ConfigError, match="need a conditional expert"):
        ExpertOptions(conditional=False, preset="tiny", cond_dropout=0.1)
    with pytest.raises(ConfigError, match="model.cond_dropout"):
        ExpertOptions(preset="tiny", cond_dropout=1.0)
    assert ExpertOptions(preset="tiny", cond_dropout=0.1, guidance_scale=2.5).guidance_scale == 2.5


def test_an_expert_starts_from_another_experts_ema_weights(tmp_path) -> None:
    source = _expert()
    with torch.no_grad():
        for p in source.ema.module.parameters():
            p.add_(0.01)  # the EMA copy differs from the raw weights: the pretrained one is what is taken
    path = tmp_path / "teacher.ckpt"
    torch.save({"state_dict": source.state_dict(), "hyper_parameters": dict(source.hparams),
                "pytorch-lightning_version": lightning.__version__,
                "spade": checkpoint_entry("expert", source.net)}, path)
    tuned = _expert(cond_dropout=0.1, init_ckpt=str(path))
    for a, b, c in zip(tuned.net.parameters(), tuned.ema.module.parameters(), source.ema.module.parameters()):
        assert torch.equal(a, c) and torch.equal(b, c)
    with pytest.raises(ValueError, match="set model.preset and model.conditional"):
        ExpertModule(conditional=True, preset="cpu_lite", num_train_timesteps=50, metrics=METRICS,
                     init_ckpt=str(path))
    with pytest.raises(FileNotFoundError, match="does not exist; pass an expert checkpoint"):
        _expert(init_ckpt=str(tmp_path / "none.ckpt"))
