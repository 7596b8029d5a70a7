"""The diffusion margin of DBC / Cond-DBC (docs/method.md, "The training objective"): how much less expert-like the student's path is.

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

The expert is the :class:`~spade.training.expert_module.ExpertModule` it was trained in
(:meth:`DiffusionMargin.from_expert`): its EMA denoiser (what its sampling uses), its noise schedule (forward
process, prediction type, timesteps) and its input builder (:func:`~spade.training.expert_module.expert_input`, also
used by its training step). The weight lambda (``lambda_dm``, ``L = L_BC + lambda_dm * L_DM``) and the options are
:class:`MarginConfig` (``conf/margin/*.yaml``, ``model.margin``), whose checks are the only ones: the config
check of ``spade.train`` runs them too.

Cost. A step with the margin adds three expert passes to BC's student forward and backward: the agent term's
forward, its backward (input gradients only: the expert's parameters do not require grad, so no weight gradients
are formed) and the expert term's forward without autograd. By default the two terms go through the expert separately;
``batch_terms=True`` sends ``[agent; expert]`` through one forward of twice the batch (the expert half detached),
which saves per-call overhead but makes the backward compute input gradients for the expert half too: on a CPU
at batch 32 it is about 1.4x slower than separate passes, so it is only worth it where per-call overhead
dominates (small batches on an accelerator). ``python -m spade.bench`` measures both.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

import torch
from torch import nn

from spade.models.diffusion import sample_timesteps
from spade.training.expert_mismatch import ExpertMismatchError
from spade.training.expert_module import ExpertModule, denoise, expert_input
from spade.training.oracle import oracle_candidates, OracleDenoiser

__all__ = ["AGENT_INPUTS", "EXPERT_KINDS", "SCORES", "UNLABELLED", "DiffusionMargin", "MarginConfig", "MarginOptionError", "legacy_margin_options",
           "sample_timesteps"]

#: ``MarginConfig.expert`` -> whether that method's expert is conditional (None: either).
EXPERT_KINDS: dict[str | None, bool | None] = {"conditional": True, "unconditional": False, None: None}

#: ``MarginConfig.score``: how one noise/timestep draw compares the agent's error e_a with the demonstration's e_d.
#: ``difference`` e_a - e_d is the paper's; it is dominated by the large errors of high timesteps, where a
#: squared-error denoiser predicts a blurred posterior mean and so rates soft images above crisp ones.
#: ``log_ratio`` log(e_a / e_d) and ``relative`` (e_a - e_d) / e_d compare each draw relative to the
#: demonstration's own error at that draw, so that the low timesteps, where a denoiser snaps off-manifold
#: (soft) pixels back to a crisp path, weigh as much as the high ones (``spade.critic`` measures the effect).
SCORES: tuple[str, ...] = ("difference", "log_ratio", "relative")
#: ``MarginConfig.agent_input``: the student's probabilities as they are (the paper), or binarised at 0.5 in the
#: forward pass with the probabilities' gradient (straight-through), so that the expert judges the path the
#: student would commit to rather than its soft map.
AGENT_INPUTS: tuple[str, ...] = ("probability", "straight_through")
#: ``MarginConfig.unlabelled``: a state without a demonstration (``labelled`` False in the batch, from
#: ``data.unlabelled_dir``) gets no BC term; its margin is the agent's error alone (``agent``: e_a, the reference's
#: error taken as 0), or the difference against a sample of the teacher drawn as the reference (``sample``; the
#: oracle's sample is a member of the instance's plausible set drawn at random, a neural teacher's is not built).
UNLABELLED: tuple[str, ...] = ("agent", "sample")
#: Floor (in the expert's own error units) under the demonstration's error in the scale-free scores.
ERROR_FLOOR = 1e-6

#: Keys of the options as older checkpoints store them (hyper-parameter ``guidance``) -> now.
LEGACY_KEYS: dict[str, str] = {"weight": "lambda_dm"}


def legacy_margin_options(guidance: Mapping[str, Any]) -> dict[str, Any]:
    """The ``margin`` options of a student checkpoint written before the rename, from its ``guidance`` entry
    (``weight`` is ``lambda_dm``; the other keys kept their names)."""
    return {LEGACY_KEYS.get(k, k): v for k, v in dict(guidance).items()}


class MarginOptionError(ValueError):
    """A margin option of the wrong type or out of range. ``str()`` names the option (``lambda_dm=-1 ...``);
    :meth:`at` names it under a config path (``model.margin.lambda_dm=-1 ...``)."""

    def __init__(self, key: str, template: str) -> None:
        self.key, self.template = key, template
        super().__init__(template.format(key=key))

    def at(self, prefix: str) -> str:
        """The message with the option's key as ``prefix + key`` (e.g. ``prefix="model.margin."``)."""
        return self.template.format(key=prefix + self.key)


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


@dataclass(frozen=True)
class MarginConfig:
    """Options of the diffusion margin; ``__post_init__`` holds every check of them (the config check of
    ``spade.train`` builds one too, so that a bad value stops the run before anything is made)."""

    lambda_dm: float = 1.0  # lambda in L_total = L_BC + lambda * L_DM
    clip: str = "sample"  # "sample" (E[max(.,0)]) or "batch" (max(E[.],0))
    antithetic: bool = True  # half the timesteps t, half T-1-t
    num_noise: int = 1  # K noise draws per instance, averaged
    t_min: int = 0
    t_max: int | None = None  # exclusive; None = the schedule's T
    batch_terms: bool = False  # one expert forward over [agent; expert] (see the module docstring for when it pays)
    # Which expert the method needs: "conditional" (Cond-DBC), "unconditional" (DBC); None accepts either.
    expert: str | None = None
    # How one draw compares the two terms (SCORES): the paper's difference, or a scale-free comparison.
    score: str = "difference"
    # How the student's probability map reaches the expert (AGENT_INPUTS).
    agent_input: str = "probability"
    # The oracle teacher (spade.training.oracle): the exact denoiser of each training instance's plausible set in
    # place of the expert's network, under the expert's schedule (expert_ckpt); needs training data with alternatives.
    oracle: bool = False
    # How the margin treats a state without a demonstration (data.unlabelled_dir, UNLABELLED): the agent term alone,
    # or against a sample of the teacher as the reference (the oracle's: a member of the plausible set at random).
    unlabelled: str = "agent"

    def __post_init__(self) -> None:
        lam = self.lambda_dm
        fix = "set it to a number >= 0 (lambda; 0 turns the margin off)"
        if not (isinstance(lam, (int, float)) and not isinstance(lam, bool) and math.isfinite(lam)):
            raise MarginOptionError("lambda_dm", "{key}=" + f"{lam!r} is not a number; {fix}")
        if lam < 0:
            raise MarginOptionError("lambda_dm", "{key}=" + f"{lam:g} is out of range; {fix}")
        self._choice("clip", ["sample", "batch"])
        self._choice("expert", [k for k in EXPERT_KINDS if k], none_ok=True)
        self._choice("score", list(SCORES))
        self._choice("agent_input", list(AGENT_INPUTS))
        self._choice("unlabelled", list(UNLABELLED))
        if self.unlabelled == "sample" and not self.oracle:
            raise MarginOptionError("unlabelled", "{key}=sample needs the oracle teacher (oracle=true): a neural "
                                    "teacher's own samples are not drawn during training; use {key}=agent")
        for key in ("antithetic", "batch_terms", "oracle"):
            if not isinstance(getattr(self, key), bool):
                raise MarginOptionError(key, "{key}=" + f"{getattr(self, key)!r} is not a boolean; set "
                                        "{key}=true or {key}=false")
        self._int("num_noise", 1)
        self._int("t_min", 0)
        if self.t_max is not None:
            self._int("t_max", self.t_min + 1, what=f"> t_min={self.t_min} (or null for all of the expert's)")

    def _choice(self, key: str, choices: list[str], none_ok: bool = False) -> None:
        value = getattr(self, key)
        if not (value is None and none_ok) and value not in choices:
            tail = " (or null for either)" if none_ok else ""
            raise MarginOptionError(key, "{key}=" + f"{value!r} is not one of {choices}; set " + "{key}="
                                    + f"{choices[0]} (or another of them){tail}")

    def _int(self, key: str, low: int, what: str | None = None) -> None:
        value, what = getattr(self, key), what or f">= {low}"
        if not _is_int(value):
            raise MarginOptionError(key, "{key}=" + f"{value!r} is not an integer; set it to an integer {what}")
        if value < low:
            raise MarginOptionError(key, "{key}=" + f"{value} is out of range; set it to an integer {what}")

    @classmethod
    def from_options(cls, options: Mapping[str, Any]) -> MarginConfig:
        """From the ``model.margin`` group (``expert_ckpt`` is the student's, not an option of the margin)."""
        known = {f.name for f in fields(cls)}
        options = {k: v for k, v in dict(options).items() if k != "expert_ckpt"}
        unknown = sorted(set(options) - known)
        if unknown:
            raise MarginOptionError(unknown[0], "{key} is not an option of the diffusion margin; its options are "
                                    f"{sorted(known)} (and expert_ckpt)")
        return cls(**options)

    def check_expert(self, conditional: bool, source: str) -> None:
        """Refuse an expert of the other kind than the method needs (DBC: unconditional, Cond-DBC: conditional),
        with the fix; ``expert`` None accepts either. ``source`` names the expert in the message."""
        need = EXPERT_KINDS.get(self.expert)
        if need is None or need == conditional:
            return
        wanted, have = self.expert, "conditional" if conditional else "unconditional"
        method, other = ("Cond-DBC (margin=cond_dbc)", "margin=dbc") if need else \
            ("DBC (margin=dbc)", "margin=cond_dbc")
        have_a, want_a = ("a" if conditional else "an"), ("a" if need else "an")
        raise ExpertMismatchError(
            f"{source} is {have_a} {have} expert, but {method} needs {want_a} {wanted} one; pass {want_a} {wanted} "
            f"expert ({want_a} {'cond' if need else 'uncond'}_expert_* experiment) or use {other} for this expert"
        )


class DiffusionMargin(nn.Module):
    """Computes L_DM for a frozen expert; build it with :meth:`from_expert` from the ExpertModule that trained it.

    ``expert(x_t, t[, cond])`` predicts the noise (or x0 or v: ``prediction_target``); ``conditional`` experts see
    the path channel only, conditioned on the state; unconditional ones see the 4-channel stack (state, path) with
    noise on all four channels (:func:`~spade.training.expert_module.expert_input` builds both).
    ``add_noise(x0, noise, t)`` is the schedule's forward process. ``prediction_target(x0, noise, t)`` is what
    the expert predicts (None: taken from the :class:`~spade.models.diffusion.NoiseSchedule` that ``add_noise``
    is a method of, else the noise: an epsilon expert).
    """

    def __init__(self, expert: nn.Module, add_noise, num_train_timesteps: int, conditional: bool,
                 config: MarginConfig, prediction_target=None) -> None:
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
            raise ValueError(f"margin t_max={t_max} exceeds the expert's {self.T} training timesteps")
        self.t_max = t_max

    @property
    def oracle(self) -> bool:
        """Whether the denoiser is the oracle (:class:`~spade.training.oracle.OracleDenoiser`): it needs each
        instance's plausible set (``plausible``) with every call."""
        return bool(self.config.oracle)

    @classmethod
    def from_expert(cls, expert: ExpertModule, config: MarginConfig) -> DiffusionMargin:
        """The margin of a trained :class:`~spade.training.expert_module.ExpertModule` (e.g. from
        ``load_from_checkpoint``), frozen (``eval()``, no gradients): its EMA denoiser (:meth:`ema_net`, what its
        sampling uses), its kind and its noise schedule (forward process, prediction type, training timesteps).
        The margin keeps the EMA denoiser and the schedule, not the module (whose raw training weights it does
        not need)."""
        expert.eval().requires_grad_(False)
        schedule = expert.schedule
        if config.oracle:  # the expert lends its schedule; the oracle predicts x0 of the path channel (conditional)
            return cls(OracleDenoiser(schedule.alphas_cumprod), schedule.add_noise, schedule.num_train_timesteps,
                       True, config, prediction_target=lambda x0, noise, t: x0)
        return cls(expert.ema_net(), schedule.add_noise, schedule.num_train_timesteps, expert.conditional, config,
                   prediction_target=schedule.prediction_target)

    def train(self, mode: bool = True) -> DiffusionMargin:
        # The expert stays in eval mode (frozen normalisation statistics, no dropout) whatever the student does.
        super().train(mode)
        self.expert.eval()
        return self

    def agent_path(self, student_prob: torch.Tensor) -> torch.Tensor:
        """The student's path as the expert sees it (``agent_input``): its probabilities, or their 0.5 threshold
        with the probabilities' gradient (straight-through)."""
        if self.config.agent_input == "straight_through":
            hard = (student_prob > 0.5).to(student_prob.dtype)
            return student_prob + (hard - student_prob).detach()
        return student_prob

    def draw_errors(self, agent_path: torch.Tensor, target: torch.Tensor, state: torch.Tensor, t: torch.Tensor,
                    noise: torch.Tensor, plausible: tuple[torch.Tensor, torch.Tensor] | None = None
                    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Per-sample denoising errors (agent with autograd, demonstration without) for one shared noise and
        timestep draw; ``agent_path`` is already what the expert sees (:meth:`agent_path`), ``noise`` has the
        expert input's shape (:func:`~spade.training.expert_module.expert_input`)."""
        agent_x0, cond = expert_input(state, agent_path, self.conditional)
        expert_x0, _ = expert_input(state, target, self.conditional)
        if self.oracle:
            cond = self._oracle_condition(plausible)
        return self._errors(agent_x0, expert_x0, noise, t, cond)

    def _oracle_condition(self, plausible: tuple[torch.Tensor, torch.Tensor] | None) -> tuple[torch.Tensor, torch.Tensor]:
        """The oracle's "condition": each instance's plausible set (B, n, 1, H, W) in the model's range and its mask."""
        if plausible is None:
            raise ValueError("the oracle teacher (model.margin.oracle=true) needs each training instance's plausible "
                             "set: train on data generated with alternatives (data.train_generate.set: "
                             "[{alternatives: {count: 16}}])")
        images, mask = plausible
        return oracle_candidates(images), mask

    def score(self, agent_err: torch.Tensor, expert_err: torch.Tensor, score: str | None = None) -> torch.Tensor:
        """One draw's margin per sample (``score``, default the config's): > 0 where the expert rates the agent
        worse. The critic passes each of :data:`SCORES` to compare them on the same draws."""
        score = score or self.config.score
        if score not in SCORES:
            raise ValueError(f"unknown score {score!r}; choose one of {list(SCORES)}")
        if score == "difference":
            return agent_err - expert_err
        floor = expert_err.detach().clamp_min(ERROR_FLOOR)
        if score == "log_ratio":
            return torch.log(agent_err.clamp_min(ERROR_FLOOR)) - torch.log(floor)
        return (agent_err - expert_err) / floor

    def draw(self, n: int, shape: tuple[int, ...], device: torch.device, dtype: torch.dtype,
             generator: torch.Generator | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """One (timesteps, noise) draw for ``n`` samples of expert input ``shape`` (C, H, W): timesteps in
        [t_min, t_max), antithetic when configured."""
        t = sample_timesteps(n, self.config.t_min, self.t_max, self.config.antithetic, device, generator)
        noise = torch.randn((n, *shape), device=device, dtype=dtype, generator=generator)
        return t, noise

    def denoising_error(self, x0: torch.Tensor, noise: torch.Tensor, t: torch.Tensor,
                        cond: torch.Tensor | None) -> torch.Tensor:
        """The expert's per-sample denoising error of ``x0`` (mean squared error of its prediction against its
        target, epsilon or x0) under ``noise`` at timesteps ``t``: the one formula the margin and the critic
        (:mod:`spade.training.critic`) score with."""
        x_t = self.add_noise(x0, noise, t)
        out = self.expert(x_t, t, *cond) if self.oracle else denoise(self.expert, x_t, t, cond)
        return (out - self.prediction_target(x0, noise, t)).pow(2).flatten(1).mean(1)

    def _errors(self, agent_x0: torch.Tensor, expert_x0: torch.Tensor, noise: torch.Tensor, t: torch.Tensor,
                cond: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor]:
        """Per-sample denoising errors (agent with autograd, expert without) for one shared noise and timestep."""
        if self.config.batch_terms:
            b = agent_x0.shape[0]
            x0, noise2, t2 = torch.cat([agent_x0, expert_x0.detach()]), torch.cat([noise, noise]), torch.cat([t, t])
            if cond is None:
                cond2 = None
            elif isinstance(cond, tuple):  # the oracle's plausible set and mask
                cond2 = tuple(torch.cat([c, c]) for c in cond)
            else:
                cond2 = torch.cat([cond, cond])
            err = self.denoising_error(x0, noise2, t2, cond2)
            return err[:b], err[b:].detach()
        with torch.no_grad():
            expert_err = self.denoising_error(expert_x0, noise, t, cond)
        return self.denoising_error(agent_x0, noise, t, cond), expert_err

    def margins(self, student_prob: torch.Tensor, target: torch.Tensor, state: torch.Tensor,
                generator: torch.Generator | None = None, plausible: tuple[torch.Tensor, torch.Tensor] | None = None,
                labelled: torch.Tensor | None = None) -> torch.Tensor:
        """Per-sample margins (B,), averaged over ``num_noise`` draws, before clipping; with autograd.
        ``plausible``: each instance's plausible set drawn as targets, (B, n, 1, H, W) in [0, 1] and its mask (B, n)
        (:func:`spade.data.plausible.plausible_images`): the oracle's knowledge, and the reference samples of
        ``unlabelled=sample``. ``labelled`` (B,) bool: False for a state without a demonstration (its ``target`` is
        not used; :data:`UNLABELLED`)."""
        cfg = self.config
        agent = self.agent_path(student_prob)
        channels = 1 if self.conditional else state.shape[1] + 1
        unlabelled = None if labelled is None or bool(labelled.all()) else ~labelled.bool()
        if unlabelled is not None and cfg.unlabelled == "sample":
            target = torch.where(unlabelled.view(-1, 1, 1, 1), self._reference_sample(plausible, generator), target)
        draws = []
        for _ in range(cfg.num_noise):
            t, noise = self.draw(agent.shape[0], (channels, *agent.shape[-2:]), agent.device, agent.dtype, generator)
            agent_err, expert_err = self.draw_errors(agent, target, state, t, noise, plausible)
            if unlabelled is not None and cfg.unlabelled == "agent":
                expert_err = expert_err.masked_fill(unlabelled, 0.0)
            draws.append(self.score(agent_err, expert_err))
        return torch.stack(draws).mean(0)

    @staticmethod
    def _reference_sample(plausible: tuple[torch.Tensor, torch.Tensor] | None,
                          generator: torch.Generator | None) -> torch.Tensor:
        """One member of each instance's plausible set drawn uniformly (the oracle teacher's committed sample)."""
        if plausible is None:
            raise ValueError("unlabelled=sample needs each instance's plausible set (training data with alternatives)")
        images, mask = plausible
        weights = mask.float().cpu()
        pick = torch.multinomial(weights, 1, generator=generator if generator is None or
                                 generator.device.type == "cpu" else None).squeeze(1).to(images.device)
        return images[torch.arange(images.shape[0], device=images.device), pick]

    def forward(self, student_prob: torch.Tensor, target: torch.Tensor, state: torch.Tensor,
                generator: torch.Generator | None = None, plausible: tuple[torch.Tensor, torch.Tensor] | None = None,
                labelled: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Return (L_DM, fraction of active margins). ``student_prob`` and ``target`` are (B, 1, H, W) in [0, 1];
        ``plausible`` and ``labelled`` as in :meth:`margins`."""
        margin = self.margins(student_prob, target, state, generator, plausible, labelled)
        if self.config.clip == "sample":
            loss = margin.clamp_min(0).mean()
        else:
            loss = margin.mean().clamp_min(0)
        active = (margin > 0).float().mean()
        return loss, active
