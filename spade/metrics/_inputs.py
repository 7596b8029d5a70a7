"""Input checks shared by the metrics: clear errors that name the expected layout; and their ``cat`` states."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from torchmetrics.utilities import dim_zero_cat


def to_numpy(x: torch.Tensor | np.ndarray, dtype: type = np.float32) -> np.ndarray:
    """A CPU numpy copy of a tensor on any device (detached), or the array itself."""
    if isinstance(x, torch.Tensor):
        return x.detach().to("cpu", dtype=torch.float64 if dtype == np.float64 else torch.float32).numpy()
    return np.asarray(x, dtype=dtype)


def per_instance_resolution(resolution: torch.Tensor | np.ndarray | float, b: int) -> np.ndarray:
    """Metres per pixel of each of ``b`` instances (float64, (b,)) from a scalar or one value per instance."""
    res = to_numpy(resolution, np.float64).reshape(-1)
    if res.size == 1:
        res = np.full(b, float(res[0]))
    if res.size != b or not np.all(res > 0):
        raise ValueError(f"resolution must be a positive scalar or one value per instance (B={b}), got {res}")
    return res


def check_images(x: torch.Tensor | np.ndarray, name: str, channels: int | None = 1) -> None:
    shape = tuple(x.shape)
    if len(shape) != 4 or (channels is not None and shape[1] != channels):
        want = f"(B, {channels}, H, W)" if channels is not None else "(B, C, H, W)"
        raise ValueError(f"{name} must be a {want} batch, got shape {shape}")


def check_same_batch(*named: tuple[str, torch.Tensor | np.ndarray]) -> None:
    sizes = {name: int(x.shape[0]) for name, x in named}
    if len(set(sizes.values())) > 1:
        raise ValueError(f"batch sizes differ: {sizes}; pass one row per instance in every argument")


def cat_state(values: list[torch.Tensor] | torch.Tensor) -> torch.Tensor:
    """A ``cat`` metric state as one float64 tensor (empty when nothing was added)."""
    return dim_zero_cat(values).double() if len(values) else torch.zeros(0, dtype=torch.float64)


def append_state(metric: Any, name: str, values: list[float]) -> None:
    """Add one update's per-instance ``values`` to ``metric``'s ``cat`` state ``name`` (float64, on its device)."""
    getattr(metric, name).append(torch.tensor(values, dtype=torch.float64, device=metric.device))
