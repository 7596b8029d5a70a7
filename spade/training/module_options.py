"""The typed options of the two LightningModules, :class:`StudentOptions` and :class:`ExpertOptions` (``model.*``),
in the shape of :class:`spade.training.margin.MarginConfig`: ``__post_init__`` refuses a value of the wrong type
or out of range in one line naming the full config key, its value and the fix
(:class:`~spade.utils.errors.ConfigError`, a ``ValueError``).

Each module builds its options from its constructor's arguments, and ``spade.train``'s preflight builds them from
the composed config (:func:`spade.config.options.read_options`), so each check exists once, here.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

from spade.utils.errors import ConfigError
from spade.utils.option_checks import MISSING, check_choice_value, check_int_value, check_number_value

__all__ = ["ExpertOptions", "StudentOptions"]


def _check_optimizer(optimizer: Any) -> None:
    """``model.optimizer``: a learning rate > 0 and a weight decay >= 0 (its other keys are the optimiser's)."""
    if not isinstance(optimizer, Mapping):
        return
    check_number_value("model.optimizer.lr", optimizer.get("lr", MISSING), 0, low_open=True, fix=", e.g. 1e-3")
    check_number_value("model.optimizer.weight_decay", optimizer.get("weight_decay", MISSING), 0, none_ok=True)


def _preset_names(kind: str) -> list[str]:
    from spade.models.builders import presets  # heavy: spade.models imports diffusers

    return presets(kind)


@dataclass(frozen=True)
class StudentOptions:
    """The options of :class:`~spade.training.student_module.StudentModule` (``model.*``); the margin's are
    :class:`~spade.training.margin.MarginConfig`'s, the checkpoints the preflight's."""

    node: ClassVar[str] = "model"
    role: ClassVar[str] = "student"
    target: ClassVar[str] = "spade.training.student_module.StudentModule"

    size: str = "medium"  # a student preset (spade.models.builders.presets("student"))
    bc_pos_weight: float | None = None  # weight of the path pixels in the BCE; None: plain BCE
    init_ckpt: str | None = None
    margin: Mapping[str, Any] | None = None
    optimizer: Mapping[str, Any] | None = field(default=None)

    def __post_init__(self) -> None:
        check_choice_value("model.size", self.size, _preset_names("student"))
        check_number_value("model.bc_pos_weight", self.bc_pos_weight, 0, low_open=True, none_ok=True,
                           fix=" (null: plain BCE)")
        _check_optimizer(self.optimizer)


@dataclass(frozen=True)
class ExpertOptions:
    """The options of :class:`~spade.training.expert_module.ExpertModule` (``model.*``)."""

    node: ClassVar[str] = "model"
    role: ClassVar[str] = "expert"
    target: ClassVar[str] = "spade.training.expert_module.ExpertModule"

    conditional: bool = True  # FiLM-conditioned on the state (Cond-DBC); False: the 4-channel DBC expert
    preset: str = "paper"
    ema_decay: float = 0.999
    sampler: str = "ddim"
    num_inference_steps: int = 50
    test_samples: int = 4  # two samples at least measure the spread
    num_train_timesteps: int = 1000
    optimizer: Mapping[str, Any] | None = field(default=None)
    cond_dropout: float = 0.0  # classifier-free guidance: share of training instances whose condition is dropped
    guidance_scale: float = 1.0  # classifier-free guidance at sampling: 1 the conditional score alone
    init_ckpt: str | None = None  # start from a trained expert of the same preset (fine-tuning)

    def __post_init__(self) -> None:
        kind = "cond_expert" if self.conditional is not False else "uncond_expert"
        check_choice_value("model.preset", self.preset, _preset_names(kind))
        check_number_value("model.ema_decay", self.ema_decay, 0, 1, high_open=True)
        check_choice_value("model.sampler", self.sampler, ["ddim", "ddpm"])
        check_int_value("model.num_inference_steps", self.num_inference_steps, 1)
        check_int_value("model.test_samples", self.test_samples, 2)
        check_int_value("model.num_train_timesteps", self.num_train_timesteps, 2)
        _check_optimizer(self.optimizer)
        check_number_value("model.cond_dropout", self.cond_dropout, 0, 1, high_open=True)
        check_number_value("model.guidance_scale", self.guidance_scale, 0, 20)
        if (self.cond_dropout or self.guidance_scale != 1) and self.conditional is False:
            raise ConfigError("model.cond_dropout and model.guidance_scale (classifier-free guidance) need a "
                              "conditional expert (model.conditional=true); leave them at 0 and 1")
        if self.guidance_scale != 1 and not self.cond_dropout:
            raise ConfigError(f"model.guidance_scale={self.guidance_scale} mixes in the unconditional score, which "
                              "an expert trained with model.cond_dropout=0 never learned: train it with "
                              "model.cond_dropout=0.1, or leave model.guidance_scale=1")
