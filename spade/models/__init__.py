"""SPADE's networks: the SKIPP-style student U-Nets, the two diffusion experts and their noise schedule."""

from spade.models.builders import ROLES, build_model, model_from_config, presets
from spade.models.cond_expert import COND_EXPERT_PRESETS, CondExpertUNet, ConditionalResidualBlock2D, build_cond_expert
from spade.models.diffusion import (
    BETA_SCHEDULES,
    SAMPLERS,
    NoiseSchedule,
    from_model_range,
    to_model_range,
)
from spade.models.student import PAPER_PARAMETER_COUNTS, STUDENT_PRESETS, StudentUNet, build_student
from spade.models.uncond_expert import UNCOND_EXPERT_PRESETS, ConvNeXtBlock, UncondExpertUNet, build_uncond_expert


def count_parameters(model, trainable_only: bool = True) -> int:
    """Number of (trainable) parameters; works for models built on the ``meta`` device."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad or not trainable_only)


__all__ = [
    "BETA_SCHEDULES",
    "COND_EXPERT_PRESETS",
    "PAPER_PARAMETER_COUNTS",
    "ROLES",
    "SAMPLERS",
    "STUDENT_PRESETS",
    "UNCOND_EXPERT_PRESETS",
    "CondExpertUNet",
    "ConditionalResidualBlock2D",
    "ConvNeXtBlock",
    "NoiseSchedule",
    "StudentUNet",
    "UncondExpertUNet",
    "build_cond_expert",
    "build_model",
    "build_student",
    "build_uncond_expert",
    "count_parameters",
    "from_model_range",
    "model_from_config",
    "presets",
    "to_model_range",
]
