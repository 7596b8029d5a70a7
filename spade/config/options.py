"""The typed options of the configurables ``spade.train`` builds, each checking its own types and ranges.

One dataclass per configurable, in the shape of :class:`spade.training.margin.MarginConfig`: its fields are the
options of that config node (``data``, ``model`` of a student or of an expert, the budget keys of ``trainer``),
and ``__post_init__`` refuses a value of the wrong type or out of range in one line naming the full key, its
value and the fix (:class:`~spade.utils.errors.ConfigError`). :func:`read_options` builds one from the composed
config (each key resolved in the context of the whole config: :func:`resolve`), as every command's checks do
before any work; the nodes no configurable consumes (the run's own keys, ``paths``, the store, the data's folders)
have their dataclasses beside the checks that read them. The options of a configurable live next to it, on its floor
(:class:`~spade.data.datamodule_options.DataOptions`, :class:`~spade.training.module_options.StudentOptions`,
:class:`~spade.training.module_options.ExpertOptions`; imported here for the preflight), and the data module and
the LightningModules build them from their own arguments: each check exists once. Only the trainer's budget and
:class:`ModelSource` (what is read of any model node) are defined here.

Which model options apply is found from the model's class, never from the spelling of its path:
:func:`options_of_class` maps the ``_target_`` of SPADE's two modules to their options, and asks any other
class for its ``role`` attribute (that of :class:`~spade.training.student_module.StudentModule` and
:class:`~spade.training.expert_module.ExpertModule`).

Fields keep Python types for readers and tools, but are checked here rather than by OmegaConf at compose time:
Hydra's coercion is looser than these refusals (``registry.promote=1`` would be ``True``, ``trainer.max_epochs``
carries ``-1`` and ``null`` sentinels, several fields are ``${...}`` interpolations of the ``scale`` and ``recipe``
groups), and its messages are several lines that name neither the fix nor the accepted range.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any, ClassVar, TypeVar

from omegaconf import DictConfig, OmegaConf

from spade.data.datamodule_options import DataOptions
from spade.training.module_options import ExpertOptions, StudentOptions
from spade.utils.errors import ConfigError
from spade.utils.option_checks import MISSING, check_int_value, check_number_value, is_int, is_number

__all__ = ["DataOptions", "ExpertOptions", "ModelSource", "StudentOptions", "TrainerBudget", "model_role",
           "options_of_class", "read_options", "resolve"]

Options = TypeVar("Options")
ModelOptions = StudentOptions | ExpertOptions


def resolve(cfg: DictConfig, key: str) -> Any:
    """The value at ``key``, plain and resolved in the context of the whole config (:data:`MISSING` when the
    config has no such key); an interpolation that does not resolve is one line naming the key."""
    try:
        value = OmegaConf.select(cfg, key, default=MISSING, throw_on_missing=False)
        if OmegaConf.is_config(value):
            value = OmegaConf.to_container(value, resolve=True)
        return value
    except Exception as exc:  # an interpolation that cannot be resolved
        raise ConfigError(f"{key}: cannot be resolved ({exc}); fix the interpolation or set {key}=VALUE") from None


def read_options(cfg: DictConfig, cls: type[Options], node: str | None = None) -> Options:
    """The options ``cls`` of config node ``node`` (default: ``cls.node``; ``""`` is the config's top level), each
    key resolved in the context of the whole config; keys the dataclass does not hold (paths, Lightning's other
    trainer flags) are left unresolved for their consumer, absent ones take the dataclass's default (the
    constructor's own)."""
    where = cls.node if node is None else node  # type: ignore[attr-defined]
    group = cfg if not where else OmegaConf.select(cfg, where, default=None)
    if group is None:
        return cls()
    if not isinstance(group, DictConfig):
        raise ConfigError(f"{where}={group!r} is not a group of options; choose one of the {where} configs")
    values = {f.name: resolve(cfg, f"{where}.{f.name}" if where else f.name)
              for f in fields(cls)}  # type: ignore[arg-type]
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
class ModelSource:
    """What the preflight reads of any ``model`` node, whatever its class: the class (``_target_``) and the
    checkpoints the model starts from (``init_ckpt``, ``margin.expert_ckpt``), checked against the data by the
    preflight. The class's own options are those :func:`options_of_class` names."""

    node: ClassVar[str] = "model"

    _target_: str | None = None
    init_ckpt: Any = None
    margin: Mapping[str, Any] | None = None

    @property
    def expert_ckpt(self) -> Any:
        return self.margin.get("expert_ckpt") if isinstance(self.margin, Mapping) else None


MODEL_OPTIONS: dict[str, type[StudentOptions] | type[ExpertOptions]] = {
    cls.target: cls for cls in (StudentOptions, ExpertOptions)
}


def options_of_class(target: Any) -> type[StudentOptions] | type[ExpertOptions] | None:
    """The options of the model class at ``target`` (a ``_target_``), found by the class's ``role``
    (:class:`~spade.training.student_module.StudentModule`: ``student``); None for a class SPADE has no options
    for (or none configured)."""
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
    """``student`` or ``expert`` for the configured model (:func:`options_of_class`), else None."""
    cls = options_of_class(read_options(cfg, ModelSource)._target_)
    return None if cls is None else cls.role

