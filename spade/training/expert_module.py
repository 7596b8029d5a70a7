"""``ExpertModule``: a DDPM path expert (conditional or unconditional) with EMA weights and DDIM/DDPM sampling."""

from __future__ import annotations

import time
from pathlib import Path
from collections.abc import Callable
from typing import Any

import torch
import torch.nn.functional as F
from torch.optim.swa_utils import AveragedModel

from spade.models.builders import build_model
from spade.models.diffusion import NoiseSchedule, to_model_range
from spade.training.base import PathPlanningModule
from spade.training.module_options import ExpertOptions
from spade.metrics.path_metrics import PathMetrics
from spade.metrics.preference import SpreadMetrics
from spade.training.base import pretrained_weights
from spade.training.expert_mismatch import ExpertMismatchError
from spade.training.teacher import medoid_reading, sample_maps, two_sample_paths


def ema_decay_at(step: int | torch.Tensor, max_decay: float) -> float:
    """The EMA decay after ``step`` averaged updates: diffusers' ``EMAModel`` schedule ``(1 + step) / (10 + step)``
    capped at ``max_decay``.

    A fixed decay from the first step keeps the random initial weights in the average for a long time (with 0.9999
    over 13k steps, 26 % of the average is still the first step's weights; with 0.995 over 320 steps, 20 %); the
    warm-up lets the average follow the fast early changes and only then slows to ``max_decay``.
    """
    n = float(step)
    return min(float(max_decay), (1.0 + n) / (10.0 + n))


def expert_input(state: torch.Tensor, path: torch.Tensor, conditional: bool
                 ) -> tuple[torch.Tensor, torch.Tensor | None]:
    """The expert's model input for a state (B, 3, H, W) and a path (B, 1, H, W), both in [0, 1]: ``(x0, cond)`` in
    the model's [-1, 1] range. Conditional (Cond-DBC): ``x0`` the path channel, ``cond`` the state; unconditional
    (DBC): ``x0`` the 4-channel stack (state, path), noised on all four channels, ``cond`` None.

    The one builder of the expert's input: its training step (:meth:`ExpertModule.model_input`) and the diffusion
    margin (:class:`spade.training.margin.DiffusionMargin`, for the demonstration and the student's path) use it.
    """
    if conditional:
        return to_model_range(path), to_model_range(state)
    return to_model_range(torch.cat([state, path], dim=1)), None


def null_condition(cond: torch.Tensor) -> torch.Tensor:
    """The condition of classifier-free guidance's unconditional branch: a state of zeros in the model's [-1, 1]
    range (mid-grey everywhere), which no real state (occupancy and markers near -1 or 1) resembles."""
    return torch.zeros_like(cond)


def guided(net: torch.nn.Module, x_t: torch.Tensor, t: torch.Tensor, cond: torch.Tensor, scale: float) -> torch.Tensor:
    """Classifier-free guidance (Ho and Salimans, 2022): ``u + scale (c - u)`` of the conditional output ``c`` and
    the unconditional one ``u`` (:func:`null_condition`), both in one batched call; ``scale`` 1 is the conditional
    output alone (one call), 0 the unconditional. Linear in the output, so it holds for epsilon, x0 and v
    prediction alike."""
    if scale == 1.0:
        return net(x_t, t, cond)
    both = net(torch.cat([x_t, x_t]), torch.cat([t, t]) if t.dim() else t, torch.cat([cond, null_condition(cond)]))
    c, u = both.chunk(2)
    return u + scale * (c - u)


def denoise(net: torch.nn.Module, x_t: torch.Tensor, t: torch.Tensor, cond: torch.Tensor | None) -> torch.Tensor:
    """The denoiser's output for ``x_t`` at ``t``, conditioned on ``cond`` when :func:`expert_input` gave one."""
    return net(x_t, t) if cond is None else net(x_t, t, cond)


class WarmupEMA:
    """``multi_avg_fn`` for :class:`torch.optim.swa_utils.AveragedModel` with the :func:`ema_decay_at` schedule
    (a plain class, so that the averaged model pickles and its state is just the weights and ``n_averaged``)."""

    def __init__(self, max_decay: float) -> None:
        self.max_decay = float(max_decay)

    @torch.no_grad()
    def __call__(self, ema_params: list[torch.Tensor], params: list[torch.Tensor], num_averaged: torch.Tensor) -> None:
        decay = ema_decay_at(int(num_averaged), self.max_decay)
        if ema_params and torch.is_floating_point(ema_params[0]):
            torch._foreach_lerp_(ema_params, params, 1.0 - decay)
        else:
            for e, p in zip(ema_params, params):
                e.copy_(p)


class ExpertModule(PathPlanningModule):
    """Trains a diffusion expert on demonstrations; its test step is the paper's standalone-expert row.

    Conditional (Cond-DBC): denoises the path channel, FiLM-conditioned on the 3-channel state.
    Unconditional (DBC): denoises the 4-channel stack (state, path); to predict a path for a given state it
    samples with the state channels inpainted (replaced at each step by the noised true state).
    Data live in [-1, 1]: x = 2 p - 1 for every [0, 1] channel. The options are checked by
    :class:`~spade.training.module_options.ExpertOptions`, the same checks as ``spade.train``'s preflight.
    """

    role = "expert"

    def __init__(
        self,
        conditional: bool = True,
        preset: str = "paper",
        num_train_timesteps: int = 1000,
        beta_schedule: str = "squaredcos_cap_v2",
        prediction_type: str = "epsilon",
        clip_sample: bool = True,
        ema_decay: float = 0.999,
        sampler: str = "ddim",
        num_inference_steps: int = 50,
        sample_seed: int = 0,
        test_samples: int = 4,
        optimizer: Callable[..., torch.optim.Optimizer] | None = None,
        lr_scheduler: Callable[..., Any] | None = None,
        metrics: dict | None = None,
        val_metric_batches: int | None = 1,
        grid_size: int = 8,
        image_size: int | None = None,
        marker_encoding: str | None = None,
        cond_dropout: float = 0.0,
        guidance_scale: float = 1.0,
        init_ckpt: str | None = None,
    ) -> None:
        options = ExpertOptions(conditional=conditional, preset=preset, ema_decay=ema_decay, sampler=sampler,
                                num_inference_steps=num_inference_steps, test_samples=test_samples,
                                num_train_timesteps=num_train_timesteps, cond_dropout=cond_dropout,
                                guidance_scale=guidance_scale, init_ckpt=init_ckpt)
        super().__init__(optimizer, metrics, val_metric_batches, grid_size)
        self.lr_scheduler_factory = lr_scheduler
        self.save_hyperparameters(ignore=["optimizer", "lr_scheduler"], logger=False)  # as StudentModule's
        self.conditional = options.conditional
        self.net = build_model("cond_expert" if options.conditional else "uncond_expert", options.preset)
        self.ema = AveragedModel(self.net, multi_avg_fn=WarmupEMA(options.ema_decay), use_buffers=True)
        self.ema.requires_grad_(False)
        # prediction_type: what the denoiser outputs (epsilon, sample = x0, v_prediction); training, sampling and
        # the diffusion margin all use it (NoiseSchedule.prediction_target). clip_sample: the samplers clip their
        # x0 estimate to [-1, 1] (paths are binary images in [0, 1]).
        self.schedule = NoiseSchedule(num_train_timesteps=options.num_train_timesteps, beta_schedule=beta_schedule,
                                      prediction_type=prediction_type, clip_sample=clip_sample)
        self.sample_seconds = 0.0
        self.sample_count = 0
        if options.init_ckpt:
            self.load_pretrained(options.init_ckpt)

    def load_pretrained(self, ckpt: str | Path) -> None:
        """Start from another expert's weights (its EMA copy, what it samples and judges with), for fine-tuning:
        e.g. a trained teacher taught classifier-free guidance (``model.cond_dropout``). The same network only."""
        weights = pretrained_weights(ckpt, "expert", self.net.config, "ema.module.",
                                     "set model.preset and model.conditional to the pretrained expert's")
        self.net.load_state_dict(weights)
        self.ema.module.load_state_dict(weights)

    # -- networks ------------------------------------------------------------------------------------------
    def ema_net(self) -> torch.nn.Module:
        """The EMA copy of the denoiser: what sampling (evaluation) and the diffusion margin use."""
        return self.ema.module

    def check_compatible(self, in_channels: int, image_size: tuple[int, int] | None, source: str,
                         encoding: str | None = None) -> None:
        """Raise a clear error when this expert cannot judge a student's paths on the given data: other channels,
        another window size, or start and goal markers drawn another way (``encoding``, the data's
        ``data.encoding``; an expert saved before the encoding was recorded was trained on ``binary`` discs)."""
        expected = in_channels if self.conditional else in_channels + 1
        have = self.net.condition_channels if self.conditional else self.net.in_channels
        what = "condition" if self.conditional else "input"
        if have != expected:
            raise ExpertMismatchError(
                f"expert {source} takes {have} {what} channels, the student's data need {expected}: train an "
                "expert on the same kind of data"
            )
        trained = self.hparams.get("image_size")
        if image_size is not None and trained is not None and tuple(image_size) != (trained, trained):
            raise ExpertMismatchError(
                f"expert {source} was trained on {trained} x {trained} instances, the student's are "
                f"{image_size[0]} x {image_size[1]}: use an expert trained at the same scale"
            )
        if encoding is not None and encoding != self.marker_encoding:
            raise ExpertMismatchError(
                f"expert {source} was trained on states whose start and goal are drawn as {self.marker_encoding!r} "
                f"markers, the student's data draw them as {encoding!r} (data.encoding): train the student with "
                f"data.encoding={self.marker_encoding}, or an expert with data.encoding={encoding}"
            )

    @property
    def marker_encoding(self) -> str:
        """How the states this expert was trained on draw the start and goal (:mod:`spade.data.encoding`)."""
        return str(self.hparams.get("marker_encoding") or "binary")

    def setup(self, stage: str) -> None:
        dm = getattr(self.trainer, "datamodule", None) if self._trainer is not None else None
        if dm is not None and self.hparams.get("image_size") is None:
            self.hparams["image_size"] = int(dm.image_size[0])
        if dm is not None and stage == "fit" and self.hparams.get("marker_encoding") is None:
            self.hparams["marker_encoding"] = str(getattr(dm, "encoding", "binary"))

    # -- training ------------------------------------------------------------------------------------------
    def model_input(self, batch: dict) -> tuple[torch.Tensor, torch.Tensor | None]:
        """``(x0, cond)`` of a batch (:func:`expert_input`): the demonstration is the (possibly widened,
        ``data.target_width_px``) path target, so that the expert judges the student's paths at the width the
        student learns."""
        return expert_input(batch["state"], batch.get("target", batch["path"]), self.conditional)

    def denoising_loss(self, net: torch.nn.Module, batch: dict, generator: torch.Generator | None = None,
                       cond_dropout: float = 0.0) -> torch.Tensor:
        """The denoising loss of a batch; ``cond_dropout``: the share of instances trained with the null condition
        (:func:`null_condition`), so that the same network learns the unconditional score for classifier-free
        guidance."""
        x0, cond = self.model_input(batch)
        if cond is not None and cond_dropout > 0:
            drop = torch.rand(cond.shape[0], device=cond.device, generator=generator) < cond_dropout
            cond = torch.where(drop[:, None, None, None], null_condition(cond), cond)
        noise = torch.randn(x0.shape, generator=generator, device=x0.device, dtype=x0.dtype)
        t = torch.randint(0, self.schedule.num_train_timesteps, (x0.shape[0],), device=x0.device, generator=generator)
        prediction = denoise(net, self.schedule.add_noise(x0, noise, t), t, cond)
        return self.schedule.denoising_error(prediction, x0, noise, t).mean()

    def training_step(self, batch: dict, batch_idx: int) -> torch.Tensor:
        loss = self.denoising_loss(self.net, batch, cond_dropout=float(self.hparams.get("cond_dropout") or 0.0))
        self.check_finite(loss, {"loss_denoise": loss})
        self.log("train/loss", loss, prog_bar=True, batch_size=batch["state"].shape[0])
        return loss

    def on_train_batch_end(self, outputs, batch, batch_idx: int) -> None:
        self.ema.update_parameters(self.net)

    def validation_losses(self, batch: dict) -> dict[str, torch.Tensor]:
        gen = torch.Generator(device=batch["state"].device).manual_seed(1234)
        return {"val/loss": self.denoising_loss(self.ema_net(), batch, gen)}

    # -- sampling ------------------------------------------------------------------------------------------
    @torch.no_grad()
    def sample_paths(self, state: torch.Tensor, sampler: str | None = None, num_inference_steps: int | None = None,
                     seed: int | None = None) -> torch.Tensor:
        """Path probabilities (B, 1, H, W) in [0, 1] sampled for ``state`` (B, 3, H, W)."""
        sampler = sampler or self.hparams.sampler
        steps = num_inference_steps or self.hparams.num_inference_steps
        gen = torch.Generator(device=state.device).manual_seed(self.hparams.sample_seed if seed is None else seed)
        net = self.ema_net()
        b, _, h, w = state.shape
        if self.conditional:
            cond, scale = to_model_range(state), float(self.hparams.get("guidance_scale", 1.0) or 1.0)
            x0 = self.schedule.sample(lambda x, t: guided(net, x, t, cond, scale), (b, 1, h, w), generator=gen,
                                      sampler=sampler, num_inference_steps=steps, device=state.device)
            path = x0
        else:
            known = to_model_range(state)
            x0 = self.schedule.sample(lambda x, t: net(x, t), (b, 4, h, w), generator=gen, sampler=sampler,
                                      num_inference_steps=steps, device=state.device,
                                      inpaint=(known, slice(0, 3)))
            path = x0[:, 3:4]
        return ((path + 1) / 2).clamp(0, 1)

    def predict_paths(self, batch: dict) -> torch.Tensor:
        t0 = time.perf_counter()
        prob = self.sample_paths(batch["state"])
        self.sample_seconds += time.perf_counter() - t0
        self.sample_count += batch["state"].shape[0]
        return prob

    def on_test_epoch_start(self) -> None:
        super().on_test_epoch_start()
        self.sample_seconds, self.sample_count = 0.0, 0
        self._spread = SpreadMetrics().to(self.device)
        metrics = dict(self.hparams.get("metrics") or {})
        self._mean_map = PathMetrics(**{**metrics, "fid": False}).to(self.device)
        self._medoid = PathMetrics(**{**metrics, "fid": False}).to(self.device)

    def test_step(self, batch: dict, batch_idx: int) -> None:
        """The expert as a planner. ``test_samples`` (K) independent samples of each instance: the first is the
        test of every predictor (:class:`PathPlanningModule`: ``test/planner/*`` is one sample decoded by the
        planner, what a robot asking the expert once would get); the mean of the K probability maps, decoded, is
        ``test/mean_map/*`` (what K samples buy); the first two give the spread of its planner paths against the
        generator's (``test/planner/spread_cm``, ``test/generator_spread_cm``, ``test/planner/spread_ratio``;
        :class:`~spade.metrics.preference.SpreadMetrics`): a teacher narrower than the operator's choices can only
        teach one of them. ``test/seconds_per_sample`` is the sampling time per instance and sample."""
        k = int(self.hparams.get("test_samples", 2) or 2)
        samples, seconds = sample_maps(self, batch["state"], k)
        self.sample_seconds += seconds
        self.sample_count += batch["state"].shape[0] * k
        self._test_with(samples[0], batch)
        self._mean_map.update(torch.stack(samples).mean(0), batch)
        paths = two_sample_paths(self.test_metrics.decode, samples, batch)
        medoid_reading(self._medoid, self.test_metrics.decode, samples, batch, paths)
        self._spread.update(paths[0], paths[1], batch["waypoints"], batch.get("alternatives"), batch["resolution"])

    def on_test_epoch_end(self) -> None:
        if self.sample_count:
            self.log("test/seconds_per_sample", self.sample_seconds / self.sample_count)
        spread = getattr(self, "_spread", None)
        if spread is not None:
            out = spread.compute()
            self.log_dict({"test/planner/spread_cm": out["spread_cm"], "test/planner/spread_ratio": out["spread_ratio"],
                           "test/generator_spread_cm": out["generator_spread_cm"]}, sync_dist=False)
            self._spread = None
        mean_map = getattr(self, "_mean_map", None)
        if mean_map is not None and mean_map.ape.total > 0:
            self.log_dict({f"test/mean_map/{key}": value for key, value in mean_map.compute().items()
                           if key.startswith("planner/")}, sync_dist=False)
            self._mean_map = None
        medoid = getattr(self, "_medoid", None)
        if medoid is not None and medoid.planner_ape.total > 0:
            self.log_dict({f"test/medoid/{key}": value for key, value in medoid.compute().items()
                           if key.startswith("planner/")}, sync_dist=False)
            self._medoid = None
        super().on_test_epoch_end()
