"""The oracle teacher: the exact denoiser of an instance's plausible set, a drop-in for the margin's expert.

Where the distribution of paths an operator (here: the generator) could draw from a state is known, as a finite
plausible set {x0_k} (the demonstration and its alternatives, :mod:`spade.metrics.plausible`), the best possible
denoiser under a noise schedule is known exactly: the posterior mean

    x0_hat(x_t, t) = sum_k softmax_k( -|x_t - sqrt(abar_t) x0_k|^2 / (2 (1 - abar_t)) ) x0_k.

A margin computed with it (:class:`OracleDenoiser` in place of the expert's network) is what a perfect teacher would
pass on: it separates "the neural teacher knows nothing more than the student" from "the margin cannot pass on what
the teacher knows", without training a large expert. It predicts x0 (``sample``) in the expert's [-1, 1] range and
uses the schedule of the expert it stands in for (``margin.expert_ckpt``: same timesteps, same abar).
"""

from __future__ import annotations

import torch
from torch import nn

__all__ = ["OracleDenoiser", "oracle_candidates"]


def oracle_candidates(images: torch.Tensor) -> torch.Tensor:
    """A plausible set's images (B, n, 1, H, W) in [0, 1] as the oracle's candidates, in the expert's [-1, 1]."""
    return images * 2.0 - 1.0


class OracleDenoiser(nn.Module):
    """``forward(x_t, t, candidates, mask)`` -> x0_hat (B, C, H, W): the exact posterior mean over each instance's
    candidates (B, n, C, H, W) in the model's range, ``mask`` (B, n) False for an empty slot. ``alphas_cumprod`` is
    the schedule's abar_t (T,)."""

    def __init__(self, alphas_cumprod: torch.Tensor) -> None:
        super().__init__()
        self.register_buffer("alphas_cumprod", torch.as_tensor(alphas_cumprod, dtype=torch.float64).clone(),
                             persistent=False)

    def weights(self, x_t: torch.Tensor, t: torch.Tensor, candidates: torch.Tensor,
                mask: torch.Tensor) -> torch.Tensor:
        """(B, n): the posterior probability of each candidate given ``x_t`` at ``t``."""
        if candidates.dim() != 5 or candidates.shape[0] != x_t.shape[0] or candidates.shape[2:] != x_t.shape[1:]:
            raise ValueError(f"the oracle's candidates must be (B, n, C, H, W) matching x_t {tuple(x_t.shape)}, got "
                             f"{tuple(candidates.shape)}")
        abar = self.alphas_cumprod.to(x_t.device)[t].to(x_t.dtype).view(-1, 1)
        diff = x_t[:, None] - abar.sqrt().view(-1, 1, 1, 1, 1) * candidates
        d2 = diff.pow(2).flatten(2).sum(2)  # (B, n)
        logits = -d2 / (2.0 * (1.0 - abar)).clamp_min(1e-12)
        logits = logits.masked_fill(~mask.bool(), float("-inf"))
        return torch.softmax(logits, dim=1)

    def forward(self, x_t: torch.Tensor, t: torch.Tensor, candidates: torch.Tensor,
                mask: torch.Tensor) -> torch.Tensor:
        w = self.weights(x_t, t, candidates, mask)
        return (w[:, :, None, None, None] * candidates).sum(1)
