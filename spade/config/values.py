"""The small typed getters of string keys that the commands' checks share (the keys of the configurables
``spade.train`` builds are typed by :mod:`spade.config.options` instead).

A key's value, resolved in the context of the whole config (:data:`MISSING` when the config has no such key), and
the one-line checks of an integer, a number, a choice and a boolean, each raising
:class:`~spade.utils.errors.ConfigError` that names the key, its value and the fix.
"""

from __future__ import annotations

import math
from typing import Any

from omegaconf import DictConfig, OmegaConf

from spade.utils.errors import ConfigError


MISSING = object()


def get(cfg: DictConfig, key: str) -> Any:
    try:
        value = OmegaConf.select(cfg, key, default=MISSING, throw_on_missing=False)
        if OmegaConf.is_config(value):  # plain, resolved in the context of the whole config
            value = OmegaConf.to_container(value, resolve=True)
        return value
    except Exception as exc:  # an interpolation that cannot be resolved
        raise ConfigError(f"{key}: cannot be resolved ({exc}); fix the interpolation or set {key}=VALUE") from None


def is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def unset(value: Any) -> bool:
    return value is MISSING or value in (None, "", "???")


def opt(cfg: DictConfig, key: str) -> Any:
    value = get(cfg, key)
    return None if value is MISSING else value


def folder_value(cfg: DictConfig, key: str) -> str | None:
    value = opt(cfg, key)
    return None if value in (None, "") else str(value)


def check_int(cfg: DictConfig, key: str, low: int | None = None, high: int | None = None, *, none_ok: bool = False,
               extra: tuple[int, ...] = (), fix: str = "") -> None:
    check_int_value(key, get(cfg, key), low, high, none_ok=none_ok, extra=extra, fix=fix)


def check_int_value(key: str, value: Any, low: int | None = None, high: int | None = None, *,
                     none_ok: bool = False, extra: tuple[int, ...] = (), fix: str = "") -> None:
    """:func:`check_int` of a value already read (``key`` names it in the message)."""
    if value is MISSING or (value is None and none_ok):
        return
    rng = range_text(low, high, extra)
    if not is_int(value):
        raise ConfigError(f"{key}={value!r} is not an integer; set it to an integer {rng}{fix}")
    if value in extra:
        return
    if (low is not None and value < low) or (high is not None and value > high):
        raise ConfigError(f"{key}={value} is out of range; set it to an integer {rng}{fix}")


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


def check_number_value(key: str, value: Any, low: float | None = None, high: float | None = None, *,
                        low_open: bool = False, high_open: bool = False, none_ok: bool = False,
                        fix: str = "") -> None:
    """:func:`check_number` of a value already read (``key`` names it in the message)."""
    if value is MISSING or (value is None and none_ok):
        return
    lo = "" if low is None else f"{'>' if low_open else '>='} {low:g}"
    hi = "" if high is None else f"{'<' if high_open else '<='} {high:g}"
    rng = " and ".join(x for x in (lo, hi) if x)
    if not is_number(value):
        raise ConfigError(f"{key}={value!r} is not a number; set it to a number {rng}{fix}")
    bad_low = low is not None and (value <= low if low_open else value < low)
    bad_high = high is not None and (value >= high if high_open else value > high)
    if bad_low or bad_high:
        raise ConfigError(f"{key}={value:g} is out of range; set it to a number {rng}{fix}")


def check_choice(cfg: DictConfig, key: str, choices: list[str], *, none_ok: bool = False) -> None:
    check_choice_value(key, get(cfg, key), choices, none_ok=none_ok)


def check_choice_value(key: str, value: Any, choices: list[str], *, none_ok: bool = False) -> None:
    """:func:`check_choice` of a value already read (``key`` names it in the message)."""
    if value is MISSING or (value is None and none_ok):
        return
    if value not in choices:
        raise ConfigError(f"{key}={value!r} is not one of {choices}; set {key}={choices[0]} (or another of them)")


def check_bool(cfg: DictConfig, key: str) -> None:
    """The one boolean check of every entry point: ``true`` / ``false`` (null or unset: the default), nothing else
    (Hydra reads ``maybe`` or ``1`` as a string or a number, which Python would take as true)."""
    value = get(cfg, key)
    if value is not MISSING and value is not None and not isinstance(value, bool):
        raise ConfigError(f"{key}={value!r} is not a boolean; set {key}=true or {key}=false")


def range_text(low: int | None, high: int | None, extra: tuple[int, ...]) -> str:
    parts = []
    if low is not None:
        parts.append(f">= {low}")
    if high is not None:
        parts.append(f"<= {high}")
    text = " and ".join(parts)
    if extra:
        text += " (or " + " / ".join(str(e) for e in extra) + " for no limit)"
    return text
