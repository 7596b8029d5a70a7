"""The diffusion margin: zero for the demonstration itself, positive for worse paths, gradients only to the student."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from spade.training.margin import DiffusionMargin, MarginConfig, sample_timesteps


@pytest.fixture(autouse=True)
def _seeded() -> None:
    """The denoisers below are randomly initialised: seed them so that every run checks the same margins."""
    torch.manual_seed(0)


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
    margin = DiffusionMargin(TinyDenoiser(), _add_noise, 1000, True, MarginConfig(clip=clip, num_noise=2))
    loss, active = margin(target.clone(), target, state, generator=torch.Generator().manual_seed(3))
    assert loss.item() == 0.0 and active.item() == 0.0


def test_gradients_reach_the_student_but_never_the_expert() -> None:
    state, target = _batch()
    expert = TinyDenoiser()
    before = {k: v.clone() for k, v in expert.state_dict().items()}
    margin = DiffusionMargin(expert, _add_noise, 1000, True, MarginConfig())
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
    margin = DiffusionMargin(expert, _add_noise, 1000, False, MarginConfig(clip="batch"))
    loss, _ = margin(torch.full_like(target, 0.5), target, state, generator=torch.Generator().manual_seed(0))
    assert torch.isfinite(loss)


def test_antithetic_timesteps_pair_up() -> None:
    t = sample_timesteps(8, 0, 1000, True, torch.device("cpu"), torch.Generator().manual_seed(0))
    assert torch.equal(t[:4] + t[4:], torch.full((4,), 999))
    t = sample_timesteps(5, 100, 200, True, torch.device("cpu"))
    assert t.min() >= 100 and t.max() < 200 and len(t) == 5


@pytest.mark.parametrize("bad", [dict(lambda_dm=-1.0), dict(clip="mean"), dict(num_noise=0), dict(t_min=5, t_max=5)])
def test_bad_margin_options_are_refused(bad: dict) -> None:
    with pytest.raises(ValueError):
        MarginConfig(**bad)


class AnchoredDenoiser(TinyDenoiser):
    """An expert that has memorised the demonstration ``anchor`` (in [-1, 1]): it predicts the noise exactly when
    x0 is the anchor, plus a small conv term so that it has weights. Margins of any other path are then positive."""

    def __init__(self, anchor: torch.Tensor, cond: int = 3) -> None:
        super().__init__(anchor.shape[1], cond)
        self.anchor = anchor

    def forward(self, x, t, c=None):
        anchor = self.anchor.repeat(x.shape[0] // self.anchor.shape[0], 1, 1, 1)  # [agent; expert] batches too
        abar = (1 - t.float() / 1000).view(-1, 1, 1, 1)
        return (x - abar.sqrt() * anchor) / (1 - abar).clamp_min(1e-3).sqrt() + 0.1 * super().forward(x, t, c)


def _reference_margin(expert, state, prob, target, conditional: bool, clip: str, num_noise: int, seed: int):
    """docs/method.md's training objective written out: shared noise and timestep, K draws averaged, then clipped."""
    g = torch.Generator().manual_seed(seed)
    if conditional:
        agent, demo, cond = 2 * prob - 1, 2 * target - 1, 2 * state - 1
    else:
        agent, demo, cond = 2 * torch.cat([state, prob], 1) - 1, 2 * torch.cat([state, target], 1) - 1, None
    margins = []
    for _ in range(num_noise):
        t = sample_timesteps(prob.shape[0], 0, 1000, True, torch.device("cpu"), g)
        noise = torch.randn(agent.shape, generator=g)

        def err(x0):
            eps = expert(_add_noise(x0, noise, t), t, cond) if conditional else expert(_add_noise(x0, noise, t), t)
            return (eps - noise).pow(2).flatten(1).mean(1)

        margins.append(err(agent) - err(demo).detach())
    margin = torch.stack(margins).mean(0)
    return margin.clamp_min(0).mean() if clip == "sample" else margin.mean().clamp_min(0)


@pytest.mark.parametrize("conditional", [True, False])
@pytest.mark.parametrize("clip", ["sample", "batch"])
def test_batched_and_separate_terms_equal_the_formula(conditional: bool, clip: str) -> None:
    state, target = _batch(b=6)
    if conditional:
        expert = AnchoredDenoiser(2 * target - 1)
    else:
        expert = AnchoredDenoiser(2 * torch.cat([state, target], 1) - 1, cond=0)
    logits0 = torch.randn(target.shape, generator=torch.Generator().manual_seed(5))
    results = {}
    for batch_terms in (False, True, None):  # None: the reference formula
        logits = logits0.clone().requires_grad_(True)
        if batch_terms is None:
            loss = _reference_margin(expert, state, torch.sigmoid(logits), target, conditional, clip, 2, seed=7)
        else:
            config = MarginConfig(clip=clip, num_noise=2, batch_terms=batch_terms)
            margin = DiffusionMargin(expert, _add_noise, 1000, conditional, config)
            loss, _ = margin(torch.sigmoid(logits), target, state, generator=torch.Generator().manual_seed(7))
        loss.backward()
        results[batch_terms] = (loss.detach(), logits.grad.clone())
    assert results[None][0] > 0 and results[None][1].abs().sum() > 0
    for batch_terms in (False, True):
        torch.testing.assert_close(results[batch_terms][0], results[None][0], rtol=1e-5, atol=1e-6)
        torch.testing.assert_close(results[batch_terms][1], results[None][1], rtol=1e-4, atol=1e-7)


def test_batched_terms_keep_the_expert_frozen_and_its_term_gradient_free() -> None:
    state, target = _batch()
    expert = AnchoredDenoiser(2 * target - 1)
    margin = DiffusionMargin(expert, _add_noise, 1000, True, MarginConfig(batch_terms=True))
    demo = target.clone().requires_grad_(True)  # were the expert term differentiable, this would get a gradient
    logits = torch.zeros_like(target, requires_grad=True)
    loss, _ = margin(torch.sigmoid(logits), demo, state, generator=torch.Generator().manual_seed(1))
    loss.backward()
    assert loss.item() > 0 and logits.grad.abs().sum() > 0
    assert demo.grad is None or demo.grad.abs().sum() == 0
    assert all(p.grad is None for p in expert.parameters())


@pytest.mark.parametrize("prediction_type", ["epsilon", "sample", "v_prediction"])
def test_margin_is_the_denoising_error_in_the_experts_parameterisation(prediction_type: str) -> None:
    """With a NoiseSchedule's add_noise the margin compares errors against what the expert predicts (noise, x0 or
    v), zero for the demonstration itself; with sample / v prediction the agent's target carries gradient too."""
    from spade.models.diffusion import NoiseSchedule, to_model_range

    schedule = NoiseSchedule(prediction_type=prediction_type)
    state, target = _batch()
    expert = TinyDenoiser()
    margin = DiffusionMargin(expert, schedule.add_noise, 1000, True, MarginConfig(antithetic=False))
    loss, active = margin(target.clone(), target, state, generator=torch.Generator().manual_seed(3))
    assert loss.item() == 0.0 and active.item() == 0.0

    student = (1 - target).requires_grad_(True)  # the inverted path: far from the demonstration
    gen = torch.Generator().manual_seed(5)
    loss, _ = margin(student, target, state, generator=gen)
    gen = torch.Generator().manual_seed(5)
    t = sample_timesteps(target.shape[0], 0, 1000, False, None, gen)
    noise = torch.randn(target.shape, generator=gen)
    a, d, c = to_model_range(student), to_model_range(target), to_model_range(state)

    def err(x0: torch.Tensor) -> torch.Tensor:
        out = expert(schedule.add_noise(x0, noise, t), t, c)
        return (out - schedule.prediction_target(x0, noise, t)).pow(2).flatten(1).mean(1)

    expected = (err(a) - err(d).detach()).clamp_min(0).mean()
    torch.testing.assert_close(loss, expected)
    assert loss.item() > 0
    loss.backward()
    assert student.grad is not None and student.grad.abs().sum() > 0


# -- regression: the margin of a trained-from-checkpoint expert keeps its value ---------------------------------
# Computed with the code before the margin was built from the ExpertModule (one input builder for the expert's
# training step and the margin): (expert kind, prediction type, expert training steps, margin options) ->
# the expert's training and validation losses, the student's L_DM, active share and total loss (lambda 2.5).
MARGIN_CASES = {
    "cond_eps": (True, "epsilon", 0, {}),
    "cond_x0_batch": (True, "sample", 40, {"clip": "batch", "num_noise": 2}),
    "uncond_eps": (False, "epsilon", 40, {"t_min": 3, "t_max": 90}),
    "uncond_batch": (False, "sample", 40, {"clip": "batch", "num_noise": 3}),
    "cond_v_terms": (True, "v_prediction", 40, {"batch_terms": True, "antithetic": False}),
}
MARGIN_REFERENCE = {  # denoise_net, denoise_ema, loss_dm, margin_active, loss
    "cond_eps": (1.0277615785598755, 1.0910179615020752, 0.013337463140487671, 0.25, 1.579323172569275),
    "cond_x0_batch": (0.09259437769651413, 0.12696492671966553, 1.368794322013855, 1.0, 4.967965126037598),
    "uncond_eps": (0.6070190072059631, 0.761494517326355, 0.08432020246982574, 1.0, 1.7567800283432007),
    "uncond_batch": (0.25979527831077576, 0.2606773376464844, 0.39770376682281494, 1.0, 2.540238857269287),
    "cond_v_terms": (0.7286268472671509, 0.4889547824859619, 0.3803038001060486, 1.0, 2.496738910675049),
}


def _regression_batch(size: int = 16, b: int = 4) -> dict:
    g = torch.Generator().manual_seed(0)
    state = (torch.rand(b, 3, size, size, generator=g) > 0.5).float() * 0.5
    path = (torch.rand(b, 1, size, size, generator=g) > 0.9).float()
    return {"state": state, "path": path, "target": path}


def _expert_checkpoint(path, conditional: bool, prediction_type: str, steps: int):
    """A tiny ExpertModule fitted ``steps`` Adam steps on the regression batch (its EMA then differs from the raw
    weights, and the expert prefers the demonstration), saved as a checkpoint ``load_from_checkpoint`` reads."""
    import lightning

    from spade.models.modelfile import checkpoint_entry
    from spade.training.expert_module import ExpertModule

    torch.manual_seed(0)
    module = ExpertModule(conditional=conditional, preset="tiny", prediction_type=prediction_type, ema_decay=0.9,
                          num_train_timesteps=100, metrics={"fid": False, "planner": False})
    opt = torch.optim.Adam(module.net.parameters(), lr=3e-3)
    batch, gen = _regression_batch(), torch.Generator().manual_seed(3)
    for _ in range(steps):
        opt.zero_grad()
        module.denoising_loss(module.net, batch, gen).backward()
        opt.step()
        module.ema.update_parameters(module.net)
    torch.save({"state_dict": module.state_dict(), "hyper_parameters": dict(module.hparams),
                "pytorch-lightning_version": lightning.__version__,
                "spade": checkpoint_entry("expert", module.net)}, path)
    return module


@pytest.mark.parametrize("case", sorted(MARGIN_CASES))
def test_the_margin_keeps_its_value_for_a_fixed_expert_batch_and_seed(case: str, tmp_path) -> None:
    from spade.training.student_module import StudentModule

    conditional, prediction_type, steps, options = MARGIN_CASES[case]
    ckpt = tmp_path / f"{case}.ckpt"
    expert = _expert_checkpoint(ckpt, conditional, prediction_type, steps)
    batch = _regression_batch()
    with torch.no_grad():
        denoise_net = float(expert.denoising_loss(expert.net, batch, torch.Generator().manual_seed(7)))
        denoise_ema = float(expert.validation_losses(batch)["val/loss"])
    torch.manual_seed(1)
    student = StudentModule(size="small", margin={"expert_ckpt": str(ckpt), "lambda_dm": 2.5, "expert": None,
                                                  **options})
    student.load_margin((16, 16))
    with torch.no_grad():
        student.net.head.bias.fill_(1.5)  # the student draws paths everywhere: margins well above zero
    torch.manual_seed(2)
    parts = student.losses(batch)
    got = (denoise_net, denoise_ema, *(float(parts[k].detach()) for k in ("loss_dm", "margin_active", "loss")))
    assert got == pytest.approx(MARGIN_REFERENCE[case], rel=1e-6, abs=1e-6)


def test_the_margin_is_built_from_the_expert_module_it_was_trained_in(tmp_path) -> None:
    """``StudentModule.load_margin`` loads the ExpertModule of the checkpoint and the margin takes its EMA denoiser
    (what its sampling uses), its schedule's forward process and prediction target, and its kind; the module is
    frozen. The expert's training step and the margin build the expert's input with the same function."""
    from spade.training.expert_module import expert_input
    from spade.training.student_module import StudentModule

    ckpt = tmp_path / "x0.ckpt"
    trained = _expert_checkpoint(ckpt, True, "sample", 3)
    student = StudentModule(size="small", margin={"expert_ckpt": str(ckpt), "expert": "conditional"})
    student.load_margin((16, 16))
    margin = student.margin
    ema = trained.ema_net().state_dict()
    assert all(torch.equal(v, ema[k]) for k, v in margin.expert.state_dict().items())
    raw = trained.net.state_dict()
    assert not all(torch.equal(v, raw[k]) for k, v in margin.expert.state_dict().items())  # not the raw weights
    expert = margin.add_noise.__self__
    assert expert.prediction_type == "sample" and margin.prediction_target == expert.prediction_target
    assert margin.T == 100 and margin.conditional and not margin.expert.training
    assert all(not p.requires_grad for p in margin.expert.parameters())
    batch = _regression_batch()
    x0, cond = trained.model_input(batch)
    ref_x0, ref_cond = expert_input(batch["state"], batch["path"], True)
    assert torch.equal(x0, ref_x0) and torch.equal(cond, ref_cond)


def test_margin_options_are_checked_once_and_name_the_option() -> None:
    from spade.training.margin import MarginOptionError

    with pytest.raises(MarginOptionError, match=r"^lambda_dm=-1 is out of range; set it to a number >= 0") as err:
        MarginConfig(lambda_dm=-1)
    assert err.value.at("model.margin.").startswith("model.margin.lambda_dm=-1 is out of range")
    with pytest.raises(MarginOptionError, match=r"expert='film' is not one of \['conditional', 'unconditional'\]"):
        MarginConfig(expert="film")
    with pytest.raises(MarginOptionError, match=r"t_max=5 is out of range; set it to an integer > t_min=5"):
        MarginConfig(t_min=5, t_max=5)
    with pytest.raises(MarginOptionError, match="weight is not an option of the diffusion margin"):
        MarginConfig.from_options({"weight": 1.0})  # the old name of lambda_dm
    assert MarginConfig.from_options({"expert_ckpt": "e.ckpt", "lambda_dm": 0.5}) == MarginConfig(lambda_dm=0.5)


def test_a_student_checkpoint_saved_with_guidance_hparams_loads_with_its_margin(tmp_path) -> None:
    """Older checkpoints keep the margin's options as hyper-parameter ``guidance`` with
    ``weight`` for lambda: they load with the margin mapped to ``margin`` / ``lambda_dm`` (not silently as BC)."""
    import lightning

    from spade.models.modelfile import checkpoint_entry
    from spade.training.loading import load_module
    from spade.training.margin import legacy_margin_options
    from spade.training.student_module import StudentModule

    expert = tmp_path / "expert.ckpt"
    _expert_checkpoint(expert, True, "epsilon", 0)
    old = {"expert_ckpt": str(expert), "expert": "conditional", "weight": 0.7, "clip": "batch", "num_noise": 2}
    torch.manual_seed(0)
    student = StudentModule(size="small")
    path = tmp_path / "old_student.ckpt"
    torch.save({"state_dict": student.state_dict(), "hyper_parameters": {"size": "small", "guidance": old},
                "pytorch-lightning_version": lightning.__version__,
                "spade": checkpoint_entry("student", student.net)}, path)
    loaded = load_module(path)
    assert loaded.margin_cfg == MarginConfig(lambda_dm=0.7, clip="batch", num_noise=2, expert="conditional")
    assert loaded.hparams["margin"] == legacy_margin_options(old) and "guidance" not in loaded.hparams
    assert all(torch.equal(v, student.state_dict()[k]) for k, v in loaded.state_dict().items())
    with pytest.raises(ValueError, match="not also under their old name guidance"):
        StudentModule(size="small", margin={"expert_ckpt": str(expert)}, guidance=old)


@pytest.mark.parametrize("conditional", [True, False], ids=["cond_dbc", "dbc"])
def test_the_expert_follows_its_student_through_casts_and_moves(conditional: bool, tmp_path) -> None:
    """The frozen expert moves and casts with the student (``.double()`` here; ``.to(device)`` and ``.half()`` take
    the same path, ``nn.Module._apply``), yet stays out of the student's checkpoint and optimiser."""
    from spade.training.student_module import StudentModule

    ckpt = tmp_path / "expert.ckpt"
    _expert_checkpoint(ckpt, conditional, "sample", 1)
    student = StudentModule(size="small", margin={"expert_ckpt": str(ckpt), "lambda_dm": 1.0,
                                                  "expert": "conditional" if conditional else "unconditional"})
    student.load_margin((16, 16))
    student = student.double()
    assert all(p.dtype == torch.float64 for p in student.margin.expert.parameters())
    batch = {k: v.double() for k, v in _regression_batch().items()}
    parts = student.losses(batch)
    assert parts["loss"].dtype == torch.float64 and torch.isfinite(parts["loss"])
    parts["loss"].backward()
    assert all(p.grad is None for p in student.margin.expert.parameters())
    assert not any(k.startswith(("_margin", "margin")) for k in student.state_dict())
    expert_params = {id(p) for p in student.margin.expert.parameters()}
    assert not expert_params & {id(p) for p in student.parameters()}
    student = student.float()
    assert all(p.dtype == torch.float32 for p in student.margin.expert.parameters())
