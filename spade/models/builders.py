"""One entry point to build any SPADE network, by role and preset name or from a saved ``config`` dict."""

from __future__ import annotations

import inspect
from typing import Any, Callable

from torch import nn

from spade.models.cond_expert import COND_EXPERT_PRESETS, CondExpertUNet, build_cond_expert
from spade.models.student import STUDENT_PRESETS, StudentUNet, build_student
from spade.models.uncond_expert import UNCOND_EXPERT_PRESETS, UncondExpertUNet, build_uncond_expert

_BUILDERS: dict[str, tuple[Callable[[str], nn.Module], dict, type[nn.Module]]] = {
    "student": (build_student, STUDENT_PRESETS, StudentUNet),
    "cond_expert": (build_cond_expert, COND_EXPERT_PRESETS, CondExpertUNet),
    "uncond_expert": (build_uncond_expert, UNCOND_EXPERT_PRESETS, UncondExpertUNet),
}
ROLES = tuple(_BUILDERS)


def presets(role: str) -> list[str]:
    """Preset names available for ``role``."""
    if role not in _BUILDERS:
        raise ValueError(f"unknown model role {role!r}; valid roles: {list(ROLES)}")
    return sorted(_BUILDERS[role][1])


def build_model(role: str, preset: str) -> nn.Module:
    """Build a network: ``role`` in ``student`` / ``cond_expert`` / ``uncond_expert``, ``preset`` one of :func:`presets`.

    Every model exposes ``in_channels``, ``out_channels``, ``config`` (a dict with ``role``, ``preset``, the
    constructor arguments and ``resolution_multiple``, to check a checkpoint against the data and to rebuild the
    model with :func:`model_from_config`) and, for experts, ``condition_channels`` (0 for the unconditional one).
    Build ``uncond_expert/paper`` (~1e9 parameters) under ``with torch.device("meta"):`` to inspect it cheaply.
    """
    valid = presets(role)
    if preset not in valid:
        raise ValueError(f"unknown preset {preset!r} for role {role!r}; valid presets: {valid}")
    return _BUILDERS[role][0](preset)


def model_from_config(config: dict[str, Any]) -> nn.Module:
    """Rebuild a (freshly initialised) model from a ``model.config`` dict, e.g. one stored in a checkpoint."""
    role = config.get("role")
    if role not in _BUILDERS:
        raise ValueError(f"config has role {role!r}; expected one of {list(ROLES)} (is it a model.config dict?)")
    cls = _BUILDERS[role][2]
    params = inspect.signature(cls.__init__).parameters
    model = cls(**{k: v for k, v in config.items() if k in params and k != "self"})
    model.preset = config.get("preset")
    return model


def count_parameters(model: Any, trainable_only: bool = True) -> int:
    """Number of (trainable) parameters; works for models built on the ``meta`` device."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad or not trainable_only)
