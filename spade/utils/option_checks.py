"""The one-line checks of an option's value, shared by every floor: the typed options of the configurables
(:class:`~spade.data.datamodule_options.DataOptions`, :class:`~spade.training.module_options.StudentOptions`,
:class:`~spade.training.module_options.ExpertOptions`, :class:`~spade.config.options.TrainerBudget`) and the
commands' options (each ``spade.config.*_checks`` dataclass, built by :func:`spade.config.options.read_options`).

Each check takes the option's full config key (``data.batch_size``) and its value, and raises
:class:`~spade.utils.errors.ConfigError` in one line naming the key, its value and the fix; :data:`MISSING` (a
key the config does not hold) passes every check. Nothing here imports another ``spade`` package but
:mod:`spade.utils.errors`, so the data module and the LightningModules check their arguments with the same code
as the preflight.
"""

from __future__ import annotations

import math
from typing import Any

from spade.utils.errors import ConfigError

__all__ = ["MISSING", "check_bool_value", "check_choice_value", "check_int_list_value", "check_int_value",
           "check_number_value", "is_int", "is_number", "range_text", "unset"]

MISSING = object()


def is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def unset(value: Any) -> bool:
    return value is MISSING or value in (None, "", "???")


def check_int_value(key: str, value: Any, low: int | None = None, high: int | None = None, *,
                     none_ok: bool = False, extra: tuple[int, ...] = (), fix: str = "") -> None:
    """An integer in ``[low, high]`` (or one of the sentinels ``extra``); ``key`` names it in the message."""
    if value is MISSING or (value is None and none_ok):
        return
    rng = range_text(low, high, extra)
    if not is_int(value):
        raise ConfigError(f"{key}={value!r} is not an integer; set it to an integer {rng}{fix}")
    if value in extra:
        return
    if (low is not None and value < low) or (high is not None and value > high):
        raise ConfigError(f"{key}={value} is out of range; set it to an integer {rng}{fix}")


def check_number_value(key: str, value: Any, low: float | None = None, high: float | None = None, *,
                        low_open: bool = False, high_open: bool = False, none_ok: bool = False,
                        fix: str = "") -> None:
    """A finite number between ``low`` and ``high`` (each bound open or closed); ``key`` names it in the message."""
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


def check_choice_value(key: str, value: Any, choices: list[str], *, none_ok: bool = False) -> None:
    """One of ``choices``; ``key`` names it in the message."""
    if value is MISSING or (value is None and none_ok):
        return
    if value not in choices:
        raise ConfigError(f"{key}={value!r} is not one of {choices}; set {key}={choices[0]} (or another of them)")


def check_bool_value(key: str, value: Any) -> None:
    """``true`` / ``false`` (null or unset: the default), nothing else (Hydra reads ``maybe`` or ``1`` as a string
    or a number, which Python would take as true); ``key`` names it in the message."""
    if value is not MISSING and value is not None and not isinstance(value, bool):
        raise ConfigError(f"{key}={value!r} is not a boolean; set {key}=true or {key}=false")


def check_int_list_value(key: str, value: Any, low: int | None = 1, *, none_ok: bool = False, fix: str = "") -> None:
    """A non-empty list of integers, each >= ``low`` (e.g. batch sizes: ``[0]`` is refused)."""
    if value is MISSING or (value is None and none_ok):
        return
    rng = range_text(low, None, ())
    fix = fix or f", e.g. {key}=[1,8]"
    if not isinstance(value, (list, tuple)) or not value:
        raise ConfigError(f"{key}={value!r} is not a non-empty list of integers; set it to a list of integers "
                          f"{rng}{fix}")
    for item in value:
        if not is_int(item) or (low is not None and item < low):
            raise ConfigError(f"{key}={value!r} holds {item!r}, which is not an integer {rng}; set it to a list of "
                              f"integers {rng}{fix}")


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
