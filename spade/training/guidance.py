"""The diffusion margin of DBC / Cond-DBC (DESIGN.md section 4): how much less expert-like the student's path is.

L_agent  = || eps_phi(x_t(a_hat), t [, s]) - eps ||^2,  L_expert = || eps_phi(x_t(a), t [, s]) - eps ||^2,
for an epsilon-predicting expert; in general each term is the expert's denoising error in its own
parameterisation, || f_phi(x_t(x0), t [, s]) - target(x0, eps, t) ||^2 with target eps (epsilon), x0 (sample) or
v = sqrt(abar_t) eps - sqrt(1 - abar_t) x0 (v_prediction), x0 being a_hat for the agent term and a for the expert's
(:meth:`spade.models.diffusion.NoiseSchedule.prediction_target`; with sample / v prediction the agent's target
depends on a_hat and carries its gradient too; for one x_t the three errors differ only by a per-timestep factor),
L_DM = E[max(L_agent - L_expert, 0)] (per-sample clipping, the paper's formula) or max(E[L_agent - L_expert], 0)
(per-batch clipping, DBC's official code). Agent and expert terms share noise and timestep; the expert term
carries no gradient; the expert's weights never change, but gradients flow through it into the student's
prediction.

Cost. A guided step adds three expert passes to BC's student forward and backward: the agent term's forward, its
backward (input gradients only: the expert's parameters do not require grad, so no weight gradients are formed)
and the expert term's forward without autograd. By default the two terms go through the expert separately;
``batch_terms=True`` sends ``[agent; expert]`` through one forward of twice the batch (the expert half detached),
which saves per-call overhead but makes the backward compute input gradients for the expert half too: on a CPU
at batch 32 it is about 1.4x slower than separate passes, so it is only worth it where per-call overhead
dominates (small batches on an accelerator). ``python -m spade.bench`` measures both.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from spade.models.diffusion import sample_timesteps, to_model_range
from spade.training.errors import ExpertMismatchError


#: ``GuidanceConfig.expert`` -> whether that method's expert is conditional (None: either).
EXPERT_KINDS: dict[str | None, bool | None] = {"conditional": True, "unconditional": False, None: None}


@dataclass(frozen=True)
class GuidanceConfig:
    """Options of the diffusion margin."""

    weight: float = 1.0  # lambda in L_total = L_BC + lambda * L_DM
    clip: str = "sample"  # "sample" (E[max(.,0)]) or "batch" (max(E[.],0))
    antithetic: bool = True  # half the timesteps t, half T-1-t
    num_noise: int = 1  # K noise draws per instance, averaged
    t_min: int = 0
    t_max: int | None = None  # exclusive; None = the schedule's T
    batch_terms: bool = False  # one expert forward over [agent; expert] (see the module docstring for when it pays)
    # Which expert the method needs: "conditional" (Cond-DBC), "unconditional" (DBC); None accepts either.
    expert: str | None = None

    def __post_init__(self) -> None:
        if self.weight < 0:
            raise ValueError(f"guidance weight (lambda) must be >= 0, got {self.weight}")
        if self.clip not in ("sample", "batch"):
            raise ValueError(f"guidance clip must be 'sample' or 'batch', got {self.clip!r}")
        if self.num_noise < 1:
            raise ValueError(f"guidance num_noise must be >= 1, got {self.num_noise}")
        if self.expert not in EXPERT_KINDS:
            kinds = sorted(k for k in EXPERT_KINDS if k)
            raise ValueError(f"guidance expert must be one of {kinds} (or null for either), got {self.expert!r}")
        if self.t_min < 0 or (self.t_max is not None and self.t_max <= self.t_min):
            raise ValueError(f"guidance timestep range [{self.t_min}, {self.t_max}) is empty or negative")


def check_expert_kind(wanted: str | None, conditional: bool, source: str) -> None:
    """Refuse an expert of the other kind than the guidance method needs (DBC: unconditional, Cond-DBC:
    conditional), with the fix; ``wanted`` None accepts either."""
    need = EXPERT_KINDS.get(wanted)
    if need is None or need == conditional:
        return
    have = "conditional" if conditional else "unconditional"
    method, other = ("Cond-DBC (guidance=cond_dbc)", "guidance=dbc") if need else \
        ("DBC (guidance=dbc)", "guidance=cond_dbc")
    have_a, want_a = ("a" if conditional else "an"), ("a" if need else "an")
    raise ExpertMismatchError(
        f"{source} is {have_a} {have} expert, but {method} needs {want_a} {wanted} one; pass {want_a} {wanted} expert "
        f"(an expert_{'cond' if need else 'uncond'}_* experiment) or use {other} for this expert"
    )


class DiffusionMargin(nn.Module):
    """Computes L_DM for a frozen expert.

    ``expert(x_t, t, cond)`` predicts the noise (or x0 or v: ``prediction_target``); ``conditional`` experts see
    the path channel only, conditioned on the state; unconditional ones see the 4-channel stack (state, path) with noise on all four channels.
    ``add_noise(x0, noise, t)`` is the schedule's forward process. ``prediction_target(x0, noise, t)`` is what
    the expert predicts (None: taken from the :class:`~spade.models.diffusion.NoiseSchedule` that ``add_noise``
    is a method of, else the noise: an epsilon expert).
    """

    def __init__(self, expert: nn.Module, add_noise, num_train_timesteps: int, conditional: bool,
                 config: GuidanceConfig, prediction_target=None) -> None:
        super().__init__()
        self.expert = expert.eval().requires_grad_(False)
        self.add_noise = add_noise
        if prediction_target is None:
            prediction_target = getattr(getattr(add_noise, "__self__", None), "prediction_target", None)
        self.prediction_target = prediction_target or (lambda x0, noise, t: noise)
        self.T = int(num_train_timesteps)
        self.conditional = conditional
        self.config = config
        t_max = config.t_max if config.t_max is not None else self.T
        if t_max > self.T:
            raise ValueError(f"guidance t_max={t_max} exceeds the expert's {self.T} training timesteps")
        self.t_max = t_max

    def train(self, mode: bool = True) -> "DiffusionMargin":
        # The expert stays in eval mode (frozen normalisation statistics, no dropout) whatever the student does.
        super().train(mode)
        self.expert.eval()
        return self

    def _eps(self, x_t: torch.Tensor, t: torch.Tensor, cond: torch.Tensor | None) -> torch.Tensor:
        return self.expert(x_t, t, cond) if self.conditional else self.expert(x_t, t)

    def _errors(self, agent_x0: torch.Tensor, expert_x0: torch.Tensor, noise: torch.Tensor, t: torch.Tensor,
                cond: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor]:
        """Per-sample denoising errors (agent with autograd, expert without) for one shared noise and timestep."""
        if self.config.batch_terms:
            b = agent_x0.shape[0]
            x0, noise2, t2 = torch.cat([agent_x0, expert_x0.detach()]), torch.cat([noise, noise]), torch.cat([t, t])
            out = self._eps(self.add_noise(x0, noise2, t2), t2, None if cond is None else torch.cat([cond, cond]))
            err = (out - self.prediction_target(x0, noise2, t2)).pow(2).flatten(1).mean(1)
            return err[:b], err[b:].detach()
        with torch.no_grad():
            out = self._eps(self.add_noise(expert_x0, noise, t), t, cond)
            expert_err = (out - self.prediction_target(expert_x0, noise, t)).pow(2).flatten(1).mean(1)
        out = self._eps(self.add_noise(agent_x0, noise, t), t, cond)
        agent_err = (out - self.prediction_target(agent_x0, noise, t)).pow(2).flatten(1).mean(1)
        return agent_err, expert_err

    def forward(self, student_prob: torch.Tensor, target: torch.Tensor, state: torch.Tensor,
                generator: torch.Generator | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Return (L_DM, fraction of active margins). ``student_prob`` and ``target`` are (B, 1, H, W) in [0, 1]."""
        cfg = self.config
        if self.conditional:
            agent_x0, expert_x0 = to_model_range(student_prob), to_model_range(target)
            cond = to_model_range(state)
        else:
            agent_x0 = to_model_range(torch.cat([state, student_prob], dim=1))
            expert_x0 = to_model_range(torch.cat([state, target], dim=1))
            cond = None
        b = student_prob.shape[0]
        margins = []
        for _ in range(cfg.num_noise):
            t = sample_timesteps(b, cfg.t_min, self.t_max, cfg.antithetic, student_prob.device, generator)
            noise = torch.randn(agent_x0.shape, device=agent_x0.device, dtype=agent_x0.dtype, generator=generator)
            agent_err, expert_err = self._errors(agent_x0, expert_x0, noise, t, cond)
            margins.append(agent_err - expert_err)
        margin = torch.stack(margins).mean(0)
        if cfg.clip == "sample":
            loss = margin.clamp_min(0).mean()
        else:
            loss = margin.mean().clamp_min(0)
        active = (margin > 0).float().mean()
        return loss, active
