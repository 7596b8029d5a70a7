"""Input checks shared by the metrics: clear errors that name the expected layout."""

from __future__ import annotations

import numpy as np
import torch


def to_numpy(x: torch.Tensor | np.ndarray, dtype: type = np.float32) -> np.ndarray:
    """A CPU numpy copy of a tensor on any device (detached), or the array itself."""
    if isinstance(x, torch.Tensor):
        return x.detach().to("cpu", dtype=torch.float64 if dtype == np.float64 else torch.float32).numpy()
    return np.asarray(x, dtype=dtype)


def check_images(x: torch.Tensor | np.ndarray, name: str, channels: int | None = 1) -> None:
    shape = tuple(x.shape)
    if len(shape) != 4 or (channels is not None and shape[1] != channels):
        want = f"(B, {channels}, H, W)" if channels is not None else "(B, C, H, W)"
        raise ValueError(f"{name} must be a {want} batch, got shape {shape}")


def check_same_batch(*named: tuple[str, torch.Tensor | np.ndarray]) -> None:
    sizes = {name: int(x.shape[0]) for name, x in named}
    if len(set(sizes.values())) > 1:
        raise ValueError(f"batch sizes differ: {sizes}; pass one row per instance in every argument")
