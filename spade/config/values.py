"""The small typed getters of string keys that the commands' checks share (the keys of the configurables
``spade.train`` builds are typed by :mod:`spade.config.options` instead).

A key's value, resolved in the context of the whole config (:data:`~spade.utils.option_checks.MISSING` when the
config has no such key), and the one-line checks of an integer, a number, a choice and a boolean read by key, each
raising :class:`~spade.utils.errors.ConfigError` that names the key, its value and the fix. The checks of a value
already read are :mod:`spade.utils.option_checks` (a floor the data module and the LightningModules may import).
"""

from __future__ import annotations

from typing import Any

from omegaconf import DictConfig, OmegaConf

from spade.utils.errors import ConfigError
from spade.utils.option_checks import (
    MISSING,
    check_choice_value,
    check_int_value,
    check_number_value,
    is_int,
    range_text,
)


def get(cfg: DictConfig, key: str) -> Any:
    try:
        value = OmegaConf.select(cfg, key, default=MISSING, throw_on_missing=False)
        if OmegaConf.is_config(value):  # plain, resolved in the context of the whole config
            value = OmegaConf.to_container(value, resolve=True)
        return value
    except Exception as exc:  # an interpolation that cannot be resolved
        raise ConfigError(f"{key}: cannot be resolved ({exc}); fix the interpolation or set {key}=VALUE") from None


def opt(cfg: DictConfig, key: str) -> Any:
    value = get(cfg, key)
    return None if value is MISSING else value


def folder_value(cfg: DictConfig, key: str) -> str | None:
    value = opt(cfg, key)
    return None if value in (None, "") else str(value)


def check_int(cfg: DictConfig, key: str, low: int | None = None, high: int | None = None, *, none_ok: bool = False,
               extra: tuple[int, ...] = (), fix: str = "") -> None:
    check_int_value(key, get(cfg, key), low, high, none_ok=none_ok, extra=extra, fix=fix)


def check_int_list(cfg: DictConfig, key: str, low: int | None = 1, *, none_ok: bool = False,
                    fix: str = "") -> None:
    """A non-empty list of integers, each >= ``low`` (e.g. batch sizes: ``[0]`` is refused)."""
    value = get(cfg, key)
    if value is MISSING or (value is None and none_ok):
        return
    example = f", e.g. {key}=[1,8]"
    if not isinstance(value, list) or not value:
        raise ConfigError(f"{key}={value!r} is not a non-empty list of integers; set it to a list of integers "
                          f"{range_text(low, None, ())}{fix or example}")
    for item in value:
        if not is_int(item) or (low is not None and item < low):
            raise ConfigError(f"{key}={value!r} holds {item!r}, which is not an integer {range_text(low, None, ())}; "
                              f"set it to a list of integers {range_text(low, None, ())}{fix or example}")


def check_number(cfg: DictConfig, key: str, low: float | None = None, high: float | None = None, *,
                  low_open: bool = False, high_open: bool = False, none_ok: bool = False, fix: str = "") -> None:
    check_number_value(key, get(cfg, key), low, high, low_open=low_open, high_open=high_open, none_ok=none_ok,
                        fix=fix)


def check_choice(cfg: DictConfig, key: str, choices: list[str], *, none_ok: bool = False) -> None:
    check_choice_value(key, get(cfg, key), choices, none_ok=none_ok)


def check_bool(cfg: DictConfig, key: str) -> None:
    """The one boolean check of every entry point: ``true`` / ``false`` (null or unset: the default), nothing else
    (Hydra reads ``maybe`` or ``1`` as a string or a number, which Python would take as true)."""
    value = get(cfg, key)
    if value is not MISSING and value is not None and not isinstance(value, bool):
        raise ConfigError(f"{key}={value!r} is not a boolean; set {key}=true or {key}=false")
