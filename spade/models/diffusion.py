"""Noise schedule and samplers for the diffusion experts: a thin wrapper around diffusers' schedulers.

Value range. The experts work on data in [-1, 1]. Images stored in {0, 1} or [0, 1] (path, start, goal, the
student's probability map, the occupancy encoding 0 / 0.5 / 1) are mapped with ``x = 2 * p - 1`` before
noising (:func:`to_model_range`) and back with ``p = (x + 1) / 2`` (:func:`from_model_range`); with
``clip_sample=True`` the sampler clips its x0 estimate to [-1, 1].

Schedules. ``beta_schedule`` is passed to diffusers' ``DDPMScheduler``, which accepts ``"linear"``,
``"scaled_linear"``, ``"squaredcos_cap_v2"`` (cosine, Diffusion Policy's choice; ignores beta_start/beta_end),
``"sigmoid"`` and ``"laplace"``. diffusers' ``"sigmoid"`` is ``sigmoid(linspace(-6, 6, T)) * (beta_end -
beta_start) + beta_start``, exactly DBC's ``sigmoid_beta_schedule`` (1,000 steps, 1e-4 to 0.02) in
NTURobotLearningLab/DBC. ``DDIMScheduler`` has no sigmoid option, so DDIM is built from the DDPM scheduler's
betas (``trained_betas``): both samplers always share one schedule.

Timestep spacing defaults to ``"trailing"``: with few inference steps the reverse loop starts at t = T - 1
(pure noise), which the ``"leading"`` spacing does not.
"""

from __future__ import annotations

from typing import Any, Callable

import torch
from diffusers import DDIMScheduler, DDPMScheduler

BETA_SCHEDULES = ("linear", "scaled_linear", "squaredcos_cap_v2", "sigmoid", "laplace")
PREDICTION_TYPES = ("epsilon", "sample", "v_prediction")
SAMPLERS = ("ddim", "ddpm")
TIMESTEP_SPACINGS = ("trailing", "leading", "linspace")

ModelFn = Callable[..., torch.Tensor]


def to_model_range(p: torch.Tensor) -> torch.Tensor:
    """Map an image in [0, 1] (or {0, 1}) to the experts' [-1, 1] range: ``x = 2 p - 1``."""
    return 2.0 * p - 1.0


def from_model_range(x: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`to_model_range`: ``p = (x + 1) / 2``."""
    return (x + 1.0) / 2.0


def sample_timesteps(n: int, t_min: int, t_max: int, antithetic: bool, device: torch.device | str | None = None,
                     generator: torch.Generator | None = None) -> torch.Tensor:
    """``n`` timesteps (long) uniform in [t_min, t_max); ``antithetic`` pairs t with t_min + t_max - 1 - t.

    Drawn on the generator's device (so that a CPU generator serves any device), then moved to ``device``."""
    gen_device = generator.device if generator is not None else "cpu"
    if antithetic:
        half = torch.randint(t_min, t_max, ((n + 1) // 2,), generator=generator, device=gen_device)
        t = torch.cat((half, t_min + t_max - 1 - half))[:n]
    else:
        t = torch.randint(t_min, t_max, (n,), generator=generator, device=gen_device)
    return t.to(device) if device is not None else t


class NoiseSchedule:
    """A DDPM forward process and its DDPM / DDIM reverse samplers, sharing one beta schedule.

    Args:
        num_train_timesteps: T, the number of diffusion steps the expert is trained with.
        beta_schedule: one of :data:`BETA_SCHEDULES` (see the module docstring).
        prediction_type: what the network predicts: ``"epsilon"`` (noise), ``"sample"`` (x0) or ``"v_prediction"``.
        clip_sample: clip the sampler's x0 estimate to [-clip_sample_range, clip_sample_range].
        beta_start, beta_end: ends of the linear / sigmoid schedules.
        timestep_spacing: how inference timesteps are spread over [0, T).
    """

    def __init__(
        self,
        num_train_timesteps: int = 1000,
        beta_schedule: str = "squaredcos_cap_v2",
        prediction_type: str = "epsilon",
        clip_sample: bool = True,
        beta_start: float = 1e-4,
        beta_end: float = 0.02,
        clip_sample_range: float = 1.0,
        timestep_spacing: str = "trailing",
    ) -> None:
        if beta_schedule not in BETA_SCHEDULES:
            raise ValueError(f"unknown beta_schedule {beta_schedule!r}; valid: {list(BETA_SCHEDULES)}")
        if prediction_type not in PREDICTION_TYPES:
            raise ValueError(f"unknown prediction_type {prediction_type!r}; valid: {list(PREDICTION_TYPES)}")
        if timestep_spacing not in TIMESTEP_SPACINGS:
            raise ValueError(f"unknown timestep_spacing {timestep_spacing!r}; valid: {list(TIMESTEP_SPACINGS)}")
        if num_train_timesteps < 2:
            raise ValueError(f"num_train_timesteps must be >= 2, got {num_train_timesteps}")
        self.num_train_timesteps = int(num_train_timesteps)
        self.beta_schedule = beta_schedule
        self.prediction_type = prediction_type
        self.clip_sample = bool(clip_sample)
        self.beta_start, self.beta_end = float(beta_start), float(beta_end)
        self.clip_sample_range = float(clip_sample_range)
        self.timestep_spacing = timestep_spacing
        self._train = self._make("ddpm")
        self.betas = self._train.betas.clone()
        self.alphas_cumprod = self._train.alphas_cumprod.clone()
        self._abar_cache: dict[tuple[torch.device, torch.dtype], torch.Tensor] = {}  # _alphas_cumprod_as

    @property
    def config(self) -> dict[str, Any]:
        """Constructor arguments, to store with an expert's checkpoint (``NoiseSchedule(**config)`` rebuilds it)."""
        return {
            "num_train_timesteps": self.num_train_timesteps,
            "beta_schedule": self.beta_schedule,
            "prediction_type": self.prediction_type,
            "clip_sample": self.clip_sample,
            "beta_start": self.beta_start,
            "beta_end": self.beta_end,
            "clip_sample_range": self.clip_sample_range,
            "timestep_spacing": self.timestep_spacing,
        }

    def _make(self, sampler: str) -> DDPMScheduler | DDIMScheduler:
        common = dict(
            num_train_timesteps=self.num_train_timesteps,
            prediction_type=self.prediction_type,
            clip_sample=self.clip_sample,
            clip_sample_range=self.clip_sample_range,
            timestep_spacing=self.timestep_spacing,
        )
        if sampler == "ddpm":
            return DDPMScheduler(beta_schedule=self.beta_schedule, beta_start=self.beta_start, beta_end=self.beta_end, **common)
        if sampler == "ddim":
            # set_alpha_to_one: the last step lands on the clean x0 estimate (so clip_sample keeps it in range).
            return DDIMScheduler(trained_betas=self.betas.numpy(), set_alpha_to_one=True, **common)
        raise ValueError(f"unknown sampler {sampler!r}; valid: {list(SAMPLERS)}")

    def _alphas_cumprod_as(self, x: torch.Tensor) -> torch.Tensor:
        """``alphas_cumprod`` on ``x``'s device and dtype, copied there once per (device, dtype), not every step."""
        key = (x.device, x.dtype)
        if key not in self._abar_cache:
            self._abar_cache[key] = self.alphas_cumprod.to(device=x.device, dtype=x.dtype)
        return self._abar_cache[key]

    def add_noise(self, x0: torch.Tensor, noise: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        """Forward process ``x_t = sqrt(abar_t) x0 + sqrt(1 - abar_t) noise`` (differentiable in ``x0``)."""
        if noise.shape != x0.shape:
            raise ValueError(f"noise shape {tuple(noise.shape)} must equal x0 shape {tuple(x0.shape)}")
        t = torch.as_tensor(t, device=x0.device)
        if t.dim() != 1 or t.shape[0] != x0.shape[0]:
            raise ValueError(f"t must have shape ({x0.shape[0]},), one timestep per sample, got {tuple(t.shape)}")
        if t.is_floating_point():
            raise ValueError(f"t must be integer timesteps in [0, {self.num_train_timesteps - 1}]")
        # The range is checked on the host only for CPU tensors: on an accelerator it would make the host wait for
        # the device twice per call (the margin calls this twice a step), and an index out of range stops the
        # device's own gather anyway.
        if t.device.type == "cpu" and (int(t.min()) < 0 or int(t.max()) >= self.num_train_timesteps):
            raise ValueError(f"t must be integer timesteps in [0, {self.num_train_timesteps - 1}]")
        abar = self._alphas_cumprod_as(x0)[t].view(-1, *([1] * (x0.dim() - 1)))
        return abar.sqrt() * x0 + (1.0 - abar).sqrt() * noise

    def prediction_target(self, x0: torch.Tensor, noise: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
        """What the network is trained to output for ``x_t = add_noise(x0, noise, t)``, by ``prediction_type``:
        ``noise`` (epsilon), ``x0`` (sample) or ``v = sqrt(abar_t) noise - sqrt(1 - abar_t) x0`` (v_prediction,
        diffusers' ``get_velocity``). Differentiable in ``x0`` (the diffusion margin's agent term needs that: with
        sample or v prediction the target itself depends on the student's path)."""
        if self.prediction_type == "epsilon":
            return noise
        if self.prediction_type == "sample":
            return x0
        t = torch.as_tensor(t, device=x0.device)
        abar = self._alphas_cumprod_as(x0)[t].view(-1, *([1] * (x0.dim() - 1)))
        return abar.sqrt() * noise - (1.0 - abar).sqrt() * x0

    def denoising_error(self, prediction: torch.Tensor, x0: torch.Tensor, noise: torch.Tensor,
                        t: torch.Tensor) -> torch.Tensor:
        """Per-sample mean squared error (B,) of a prediction against :meth:`prediction_target`: the expert's
        denoising loss in its own parameterisation (what training minimises and the DBC margin compares)."""
        return (prediction - self.prediction_target(x0, noise, t)).pow(2).flatten(1).mean(1)

    def random_timesteps(
        self, batch_size: int, generator: torch.Generator | None = None, antithetic: bool = True, device: torch.device | str | None = None
    ) -> torch.Tensor:
        """Uniform training timesteps (B,) long; ``antithetic`` pairs each t with T - 1 - t, as DBC's code does."""
        return sample_timesteps(batch_size, 0, self.num_train_timesteps, antithetic, device, generator)

    @torch.no_grad()
    def sample(
        self,
        model_fn: ModelFn,
        shape: tuple[int, ...],
        generator: torch.Generator | None = None,
        sampler: str = "ddim",
        num_inference_steps: int = 50,
        cond: torch.Tensor | None = None,
        eta: float = 0.0,
        device: torch.device | str | None = None,
        dtype: torch.dtype = torch.float32,
        inpaint: tuple[torch.Tensor, slice] | None = None,
    ) -> torch.Tensor:
        """Run the full reverse loop from Gaussian noise and return x0 (in [-1, 1] when ``clip_sample``).

        ``inpaint=(known, channels)`` keeps the given channels to ``known`` (B, C_known, H, W): before every
        step they are replaced by ``known`` noised to that step's level (RePaint-style conditioning of an
        unconditional model, e.g. sampling a path for a given state), and set to ``known`` at the end.

        ``model_fn(x_t, t)`` (or ``model_fn(x_t, t, cond)`` when ``cond`` is given) returns the network's
        prediction; ``t`` is a (B,) long tensor. The same ``generator`` seed gives the same samples (DDIM with
        ``eta=0`` only uses it for the initial noise; DDPM also for each step's noise).
        """
        if sampler not in SAMPLERS:
            raise ValueError(f"unknown sampler {sampler!r}; valid: {list(SAMPLERS)}")
        if not 1 <= num_inference_steps <= self.num_train_timesteps:
            raise ValueError(f"num_inference_steps must be in [1, {self.num_train_timesteps}], got {num_inference_steps}")
        if device is None:
            device = cond.device if cond is not None else "cpu"
        if cond is not None and cond.shape[0] != shape[0]:
            raise ValueError(f"cond batch size {cond.shape[0]} must equal shape[0] = {shape[0]}")
        scheduler = self._make(sampler)
        scheduler.set_timesteps(num_inference_steps, device=device)
        gen_device = generator.device if generator is not None else "cpu"
        x = torch.randn(shape, generator=generator, device=gen_device, dtype=dtype).to(device)
        x = x * scheduler.init_noise_sigma
        step_kwargs: dict[str, Any] = {"generator": generator}
        if sampler == "ddim":
            step_kwargs["eta"] = eta
        if inpaint is not None:
            known, channels = inpaint
            known = known.to(device=device, dtype=dtype)
            known_noise = torch.randn(known.shape, generator=generator, device=gen_device, dtype=dtype).to(device)
        for t in scheduler.timesteps:
            t_batch = torch.full((shape[0],), int(t), dtype=torch.long, device=device)
            if inpaint is not None:
                x[:, channels] = self.add_noise(known, known_noise, t_batch)
            out = model_fn(x, t_batch) if cond is None else model_fn(x, t_batch, cond)
            x = scheduler.step(out, t, x, **step_kwargs).prev_sample
        if inpaint is not None:
            x[:, channels] = known
        return x
