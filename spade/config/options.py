"""The typed options of the configurables ``spade.train`` builds, each checking its own types and ranges.

One dataclass per configurable, in the shape of :class:`spade.training.margin.MarginConfig`: its fields are the
options of that config node (``data``, ``model`` of a student or of an expert, the budget keys of ``trainer``),
and ``__post_init__`` refuses a value of the wrong type or out of range in one line naming the full key, its
value and the fix (:class:`~spade.utils.errors.ConfigError`). :func:`read_options` builds one from the composed
config, as the preflight does before any work; the LightningModules and the data module no longer repeat these
checks.

Which model options apply is found from the model's class, never from the spelling of its path:
:func:`model_options_type` maps the ``_target_`` of SPADE's two modules to their options, and asks any other
class for its ``role`` attribute (that of :class:`~spade.training.student_module.StudentModule` and
:class:`~spade.training.expert_module.ExpertModule`).

Fields keep Python types for readers and tools, but are checked here rather than by OmegaConf at compose time:
Hydra's coercion is looser than these refusals (``registry.promote=1`` would be ``True``, ``trainer.max_epochs``
carries ``-1`` and ``null`` sentinels, several fields are ``${...}`` interpolations of the ``scale`` and ``recipe``
groups), and its messages are several lines that name neither the fix nor the accepted range.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any, ClassVar, TypeVar

from omegaconf import DictConfig, OmegaConf

from spade.config.values import (
    MISSING,
    check_choice_value,
    check_int_value,
    check_number_value,
    get,
    is_int,
    is_number,
)
from spade.utils.errors import ConfigError

__all__ = ["DataOptions", "ExpertOptions", "StudentOptions", "TrainerBudget", "model_options_type", "model_role",
           "read_options"]

Options = TypeVar("Options")


def read_options(cfg: DictConfig, cls: type[Options], node: str | None = None) -> Options:
    """The options ``cls`` of config node ``node`` (default: ``cls.node``), each key resolved in the context of the
    whole config; keys the dataclass does not hold (``_target_``, paths, Lightning's other trainer flags) are left
    unresolved for their consumer, absent ones take the dataclass's default (the constructor's own)."""
    where = node or cls.node  # type: ignore[attr-defined]
    group = OmegaConf.select(cfg, where, default=None)
    if group is None:
        return cls()
    if not isinstance(group, DictConfig):
        raise ConfigError(f"{where}={group!r} is not a group of options; choose one of the {where} configs")
    values = {f.name: get(cfg, f"{where}.{f.name}") for f in fields(cls)}  # type: ignore[arg-type]
    return cls(**{k: v for k, v in values.items() if v is not MISSING})


@dataclass(frozen=True)
class TrainerBudget:
    """How long the Lightning trainer runs and how often it validates and logs (``trainer.*``): the keys a run's
    numbers depend on. The trainer's other flags are Lightning's to check."""

    node: ClassVar[str] = "trainer"

    max_epochs: int | None = None  # -1: no limit (then max_steps must stop the run)
    max_steps: int | None = None  # -1: no limit
    check_val_every_n_epoch: int | None = None
    log_every_n_steps: int | None = None
    accumulate_grad_batches: int | None = None
    num_sanity_val_steps: int | None = None  # -1: the whole validation set
    gradient_clip_val: float | None = None
    limit_train_batches: int | float | None = None  # a fraction in [0, 1] or a whole number of batches
    limit_val_batches: int | float | None = None
    limit_test_batches: int | float | None = None

    def __post_init__(self) -> None:
        check_int_value("trainer.max_epochs", self.max_epochs, 1, none_ok=True, extra=(-1,),
                        fix=", e.g. trainer.max_epochs=2")
        check_int_value("trainer.max_steps", self.max_steps, 1, none_ok=True, extra=(-1,),
                        fix=", e.g. trainer.max_steps=100")
        if self.max_epochs == -1 and self.max_steps in (-1, None):
            raise ConfigError("trainer.max_epochs=-1 and trainer.max_steps=-1 never stop; set trainer.max_epochs=N")
        for key in ("check_val_every_n_epoch", "log_every_n_steps", "accumulate_grad_batches"):
            check_int_value(f"trainer.{key}", getattr(self, key), 1, none_ok=True)
        check_int_value("trainer.num_sanity_val_steps", self.num_sanity_val_steps, 0, none_ok=True, extra=(-1,))
        check_number_value("trainer.gradient_clip_val", self.gradient_clip_val, 0, none_ok=True)
        for key in ("limit_train_batches", "limit_val_batches", "limit_test_batches"):
            value = getattr(self, key)
            if value is None:
                continue
            if not ((is_int(value) and value >= 0) or (is_number(value) and 0 <= value <= 1)):
                raise ConfigError(f"trainer.{key}={value!r} must be a fraction in [0, 1] or a whole number of "
                                  "batches >= 0")


@dataclass(frozen=True)
class DataOptions:
    """The loader options of :class:`~spade.data.datamodule.PathDataModule` (``data.*``; its folders and
    generation settings are checked against the disk by :mod:`spade.config.dataset_checks`). Defaults are the
    data module's."""

    node: ClassVar[str] = "data"

    batch_size: int = 32
    eval_batch_size: int | None = None
    num_workers: int = 0  # 0: load in the main process
    val_fraction: float = 0.1
    split_seed: int | None = 0
    max_train_instances: int | None = None
    max_test_instances: int | None = None
    target_width_px: int = 1  # the path target's width in pixels, odd
    encoding: str = "binary"  # the start and goal markers (spade.data.encoding.MARKER_ENCODINGS)

    def __post_init__(self) -> None:
        from spade.data.encoding import MARKER_ENCODINGS

        check_int_value("data.batch_size", self.batch_size, 1, fix=", e.g. data.batch_size=32")
        check_int_value("data.eval_batch_size", self.eval_batch_size, 1, none_ok=True)
        check_int_value("data.num_workers", self.num_workers, 0, fix=" (0 loads in the main process)")
        check_number_value("data.val_fraction", self.val_fraction, 0, 1, high_open=True,
                           fix=", e.g. data.val_fraction=0.15")
        check_int_value("data.split_seed", self.split_seed, none_ok=True)
        check_int_value("data.max_train_instances", self.max_train_instances, 1, none_ok=True)
        check_int_value("data.max_test_instances", self.max_test_instances, 1, none_ok=True)
        width = self.target_width_px
        if not is_int(width) or width < 1 or width % 2 == 0:
            raise ConfigError(f"data.target_width_px={width!r} is not an odd number of pixels >= 1; set it to 1 (or "
                              "3, 5, ...)")
        if self.encoding not in MARKER_ENCODINGS:
            raise ConfigError(f"data.encoding={self.encoding!r} is not a marker encoding; use one of "
                              f"{list(MARKER_ENCODINGS)} (binary: the paper's discs)")


def _check_optimizer(optimizer: Any) -> None:
    """``model.optimizer``: a learning rate > 0 and a weight decay >= 0 (its other keys are the optimiser's)."""
    if not isinstance(optimizer, Mapping):
        return
    check_number_value("model.optimizer.lr", optimizer.get("lr", MISSING), 0, low_open=True, fix=", e.g. 1e-3")
    check_number_value("model.optimizer.weight_decay", optimizer.get("weight_decay", MISSING), 0, none_ok=True)


def _preset_names(kind: str) -> list[str]:
    from spade.models import presets  # heavy: spade.models imports diffusers

    return presets(kind)


@dataclass(frozen=True)
class StudentOptions:
    """The options of :class:`~spade.training.student_module.StudentModule` (``model.*``) that it does not check
    itself; the margin's are :class:`~spade.training.margin.MarginConfig`'s, the checkpoints the preflight's."""

    node: ClassVar[str] = "model"
    role: ClassVar[str] = "student"
    target: ClassVar[str] = "spade.training.student_module.StudentModule"

    size: str = "medium"  # a student preset (spade.models.presets("student"))
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

    def __post_init__(self) -> None:
        kind = "cond_expert" if self.conditional is not False else "uncond_expert"
        check_choice_value("model.preset", self.preset, _preset_names(kind))
        check_number_value("model.ema_decay", self.ema_decay, 0, 1, high_open=True)
        check_choice_value("model.sampler", self.sampler, ["ddim", "ddpm"])
        check_int_value("model.num_inference_steps", self.num_inference_steps, 1)
        check_int_value("model.test_samples", self.test_samples, 2)
        check_int_value("model.num_train_timesteps", self.num_train_timesteps, 2)
        _check_optimizer(self.optimizer)


MODEL_OPTIONS: dict[str, type[StudentOptions] | type[ExpertOptions]] = {
    cls.target: cls for cls in (StudentOptions, ExpertOptions)
}


def model_options_type(cfg: DictConfig) -> type[StudentOptions] | type[ExpertOptions] | None:
    """The options of the configured model (``model._target_``): those of its class, found by the class's
    ``role`` (:class:`~spade.training.student_module.StudentModule`: ``student``); None for a class SPADE has no
    options for (or none configured)."""
    target = get(cfg, "model._target_")
    if not isinstance(target, str) or not target:
        return None
    if target in MODEL_OPTIONS:
        return MODEL_OPTIONS[target]
    from hydra.utils import get_class

    try:
        role = getattr(get_class(target), "role", None)
    except Exception:  # noqa: BLE001 - not importable: instantiating it names the problem
        return None
    return next((cls for cls in MODEL_OPTIONS.values() if cls.role == role), None)


def model_role(cfg: DictConfig) -> str | None:
    """``student`` or ``expert`` for the configured model (:func:`model_options_type`), else None."""
    cls = model_options_type(cfg)
    return None if cls is None else cls.role
