"""SPADE's networks: the SKIPP-style student U-Nets, the two diffusion experts and their noise schedule.

The names below are imported on first use (PEP 562), so that a torch-free module of this package
(:mod:`~spade.models.paper_sizes`, :mod:`~spade.models.onnx_session`) can be imported without torch.
"""

from __future__ import annotations

from typing import Any

from spade.utils.lazy_exports import lazy_exports

_HOMES = {
    "ROLES": "builders", "build_model": "builders", "model_from_config": "builders", "presets": "builders",
    "COND_EXPERT_PRESETS": "cond_expert", "CondExpertUNet": "cond_expert",
    "ConditionalResidualBlock2D": "cond_expert", "build_cond_expert": "cond_expert",
    "BETA_SCHEDULES": "diffusion", "SAMPLERS": "diffusion", "NoiseSchedule": "diffusion",
    "from_model_range": "diffusion", "to_model_range": "diffusion",
    "PAPER_PARAMETER_COUNTS": "paper_sizes",
    "STUDENT_PRESETS": "student", "StudentUNet": "student", "build_student": "student",
    "UNCOND_EXPERT_PRESETS": "uncond_expert", "ConvNeXtBlock": "uncond_expert", "UncondExpertUNet": "uncond_expert",
    "build_uncond_expert": "uncond_expert",
}
"""Where each name lives."""


def count_parameters(model: Any, trainable_only: bool = True) -> int:
    """Number of (trainable) parameters; works for models built on the ``meta`` device."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad or not trainable_only)


__getattr__ = lazy_exports(__name__, _HOMES, globals())


__all__ = sorted([*_HOMES, "count_parameters"])
