"""Diffusion experts: seconds per sample of DDIM-k and of the full DDPM loop, and what DDIM-k costs in APE.

Long loops (1,000 DDPM steps of the 9.2M-parameter expert at 128 px take minutes per sample on a CPU) are timed
over their first ``max_timed_steps`` denoiser calls of the real sampling loop and extrapolated linearly (every
step costs the same: one denoiser call and one scheduler update); rows say so with ``extrapolated``.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import torch

from spade.perf.student import forward_gflop
from spade.deploy.export import example_states
from spade.metrics.ape import APE
from spade.metrics.hausdorff import HausdorffCount
from spade.models.builders import count_parameters
from spade.training.expert_module import ExpertModule


class _Stop(Exception):
    """Raised by a forward hook to end a sampling loop after a given number of denoiser calls."""


def _run(module: Any, state: torch.Tensor, sampler: str, steps: int, calls: int | None, seed: int) -> float:
    """Seconds to run ``module.sample_paths`` for ``steps`` steps, or only its first ``calls`` denoiser calls."""
    net = module.ema_net()
    count = 0

    def hook(*_: Any) -> None:
        nonlocal count
        count += 1
        if calls is not None and count >= calls:
            raise _Stop

    handle = net.register_forward_hook(hook)
    t0 = time.perf_counter()
    try:
        module.sample_paths(state, sampler=sampler, num_inference_steps=steps, seed=seed)
    except _Stop:
        pass
    finally:
        handle.remove()
    if state.is_cuda:  # CUDA runs asynchronously: the loop's time is the device's
        torch.cuda.synchronize(state.device)
    return time.perf_counter() - t0


def sampling_seconds(module: Any, state: torch.Tensor, sampler: str, steps: int, max_timed_steps: int | None = None,
                     warmup_steps: int = 2, seed: int = 0) -> dict[str, Any]:
    """Seconds per sample of ``module.sample_paths(state, sampler, steps)`` (an :class:`ExpertModule`).

    When ``steps > max_timed_steps`` only the first ``max_timed_steps`` steps run and the time is extrapolated.
    """
    _run(module, state, sampler, steps, min(warmup_steps, steps), seed)
    timed = steps if not max_timed_steps or steps <= max_timed_steps else int(max_timed_steps)
    seconds = _run(module, state, sampler, steps, None if timed == steps else timed, seed) * steps / timed
    return {"sampler": sampler, "steps": steps, "seconds_per_sample": seconds / state.shape[0],
            "timed_steps": timed, "extrapolated": timed != steps, "batch": int(state.shape[0])}


def expert_sampling_costs(conditional: bool, preset: str, image_size: int, ddim_steps: Sequence[int],
                          max_timed_steps: int = 20, num_train_timesteps: int = 1000, batch: int = 1) -> dict[str, Any]:
    """Seconds per sample of a (randomly initialised) expert preset: DDIM at each of ``ddim_steps`` and DDPM over
    all ``num_train_timesteps`` steps, with the speed-up of each DDIM setting over DDPM."""
    module = ExpertModule(conditional=conditional, preset=preset, num_train_timesteps=num_train_timesteps).eval()
    net = module.ema_net()
    state = example_states(batch, (image_size, image_size), seed=0)
    x = torch.zeros(1, net.in_channels, image_size, image_size)
    t = torch.zeros(1, dtype=torch.long)
    gflop = forward_gflop(net, x, t, state[:1] * 2 - 1) if conditional else forward_gflop(net, x, t)
    rows = [sampling_seconds(module, state, "ddim", k, max_timed_steps) for k in ddim_steps]
    ddpm = sampling_seconds(module, state, "ddpm", num_train_timesteps, max_timed_steps)
    for row in rows:
        row["speedup_vs_ddpm"] = ddpm["seconds_per_sample"] / row["seconds_per_sample"]
    return {"expert": "cond" if conditional else "uncond", "preset": preset, "image_size": image_size,
            "params": count_parameters(net, trainable_only=False), "gflop_per_call": gflop, "ddim": rows, "ddpm": ddpm}


def sampler_quality(module: Any, batch: dict[str, torch.Tensor], settings: Sequence[tuple[str, int]], seed: int = 0,
                    hd_threshold: float = 19.0) -> list[dict[str, Any]]:
    """APE / Hd19 / failures of paths sampled for ``batch`` by each (sampler, steps) setting, all from the same
    initial noise (``seed``), with seconds per sample measured over the whole loop."""
    rows = []
    n = int(batch["state"].shape[0])
    for sampler, steps in settings:
        t0 = time.perf_counter()
        prob = module.sample_paths(batch["state"], sampler=sampler, num_inference_steps=int(steps), seed=seed)
        seconds = time.perf_counter() - t0
        ape, hd = APE(), HausdorffCount(threshold=hd_threshold)
        ape.update(prob, batch["state"], batch["waypoints"], batch["resolution"])
        hd.update(prob, batch["path"])
        a, h = ape.compute(), hd.compute()
        rows.append({
            "sampler": sampler, "steps": int(steps), "samples": n, "seconds_per_sample": seconds / n,
            "ape_cm": float(a["ape_cm"]), "ape_median_cm": float(a["ape_median_cm"]), "failures": int(a["failures"]),
            "hd_count": int(h[hd.name]), "hd_threshold": hd_threshold,
        })
    return rows
