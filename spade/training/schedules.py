"""Learning-rate schedules for ``configure_optimizers``: built from a Hydra ``_partial_`` (``model.lr_scheduler``).

``warmup_cosine``: linear warm-up from ``warmup_start`` x lr to lr over the first steps, then a cosine decay to
``min_lr_ratio`` x lr at the last training step (Diffusion Policy and TransPath train with such a schedule; the
constant rate left validation curves that jump from epoch to epoch). Stepped every optimisation step; the
number of steps comes from the trainer (``estimated_stepping_batches``: max_epochs or max_steps).
"""

from __future__ import annotations

import math

import torch
from torch.optim.lr_scheduler import LambdaLR


def warmup_cosine_factor(step: int, total_steps: int, warmup_steps: int, min_lr_ratio: float = 0.0,
                         warmup_start: float = 0.0) -> float:
    """The multiplier of the base learning rate after ``step`` optimisation steps (0-based)."""
    total_steps = max(1, int(total_steps))
    warmup_steps = max(0, min(int(warmup_steps), total_steps - 1))
    if step < warmup_steps:
        return warmup_start + (1.0 - warmup_start) * (step + 1) / warmup_steps
    progress = min(1.0, (step - warmup_steps) / max(1, total_steps - warmup_steps))
    return min_lr_ratio + (1.0 - min_lr_ratio) * 0.5 * (1.0 + math.cos(math.pi * progress))


def warmup_cosine(optimizer: torch.optim.Optimizer, total_steps: int, warmup_fraction: float = 0.05,
                  warmup_steps: int | None = None, min_lr_ratio: float = 0.01, warmup_start: float = 0.0) -> LambdaLR:
    """A :class:`LambdaLR` of :func:`warmup_cosine_factor`; ``warmup_steps`` (when given) overrides
    ``warmup_fraction`` of ``total_steps``."""
    if total_steps < 1:
        raise ValueError(f"warmup_cosine needs total_steps >= 1, got {total_steps}")
    if not 0.0 <= warmup_fraction < 1.0:
        raise ValueError(f"warmup_fraction must be in [0, 1), got {warmup_fraction}")
    if not 0.0 <= min_lr_ratio <= 1.0:
        raise ValueError(f"min_lr_ratio must be in [0, 1], got {min_lr_ratio}")
    warm = int(warmup_steps) if warmup_steps is not None else int(round(warmup_fraction * total_steps))
    return LambdaLR(optimizer, lambda step: warmup_cosine_factor(step, total_steps, warm, min_lr_ratio, warmup_start))
