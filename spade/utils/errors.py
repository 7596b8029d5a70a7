"""User errors: the config error every check raises, and the entry points' one-line report of such errors.

A user error means the user must change something (a key, a file, a folder); the entry points report it as one
line on stderr with exit status 2 instead of a traceback (``HYDRA_FULL_ERROR=1`` shows the traceback instead).
Which exceptions count is the caller's: :func:`spade.config.refusals.user_errors` lists every
package's, ``python -m spade.data.verify`` only the dataset's.
"""

from __future__ import annotations

import functools
import os
import shutil
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any
from spade.utils.console import quiet_library_deprecations, quiet_third_party_advertising


class UserError(Exception):
    """Something the user must change (a key, a file, a folder): every entry point reports it as one line, without a
    traceback, and exits with status 2. Each package's user errors derive from it (and keep their builtin base,
    ``ValueError`` or ``RuntimeError``, for callers that catch those)."""


class ConfigError(UserError, ValueError):
    """A user error in the config, reported as one line (key, value, fix) without a traceback."""


Errors = tuple[type[BaseException], ...]


def remove_untouched_run_dir() -> None:
    """Remove the Hydra run folder of a refused command when it holds only what Hydra itself put there (``.hydra/``
    and the job's log): a refusal leaves no run folder behind. A folder holding anything else is kept."""
    try:
        from hydra.core.hydra_config import HydraConfig

        if not HydraConfig.initialized():
            return
        hydra_cfg = HydraConfig.get()
        out = Path(str(hydra_cfg.runtime.output_dir))
        own = {".hydra", f"{hydra_cfg.job.name}.log"}
        if out.is_dir() and {p.name for p in out.iterdir()} <= own:
            shutil.rmtree(out, ignore_errors=True)
    except Exception:  # noqa: BLE001 - tidying must never hide the error being reported
        return


def _caused_by(exc: BaseException, kinds: Errors) -> BaseException | None:
    """``exc`` or the exception it was raised from that is one of ``kinds``: a user error raised inside a constructor
    that Hydra instantiates reaches the entry point wrapped in Hydra's ``InstantiationException``."""
    seen: BaseException | None = exc
    while seen is not None:
        if isinstance(seen, kinds):
            return seen
        seen = seen.__cause__
    return None


def exit_on_errors(errors: Errors | Callable[[], Errors]) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """Wrap an entry point's task function: an exception of ``errors`` (a tuple, or a function returning one when
    such an exception occurs) ends the process with one line and exit status 2.

    ``HYDRA_FULL_ERROR=1`` re-raises it instead, for Hydra's full traceback.
    """

    def decorate(fn: Callable[..., Any]) -> Callable[..., Any]:
        @functools.wraps(fn)
        def wrapper(*args: Any, **kwargs: Any) -> Any:
            try:
                return fn(*args, **kwargs)
            except BaseException as exc:
                user = _caused_by(exc, errors() if callable(errors) else errors)
                if user is None:
                    raise
                if os.environ.get("HYDRA_FULL_ERROR") == "1":
                    raise
                print(f"error: {user}", file=sys.stderr, flush=True)
                remove_untouched_run_dir()
                raise SystemExit(2) from None

        return wrapper

    return decorate


# -- Hydra's own errors -------------------------------------------------------------------------------------------
_task_started = False


def task(fn: Callable[..., Any]) -> Callable[..., Any]:
    """Mark an entry point's task function (under ``@hydra.main``) as started: Hydra composed its config."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        global _task_started
        _task_started = True
        return fn(*args, **kwargs)

    return wrapper


def run_entry_point(main: Callable[[], Any]) -> None:
    """Run a ``@hydra.main`` function. An error Hydra reports before the task starts (composing the config: an
    unknown ``+experiment=``, a key without its ``+``, a malformed override) exits with status 2, as every user
    error does, instead of Hydra's 1; its message is Hydra's own."""
    global _task_started
    _task_started = False
    quiet_third_party_advertising()  # Lightning's product tips are not SPADE's output
    quiet_library_deprecations()  # nor one library's deprecation notes about another
    try:
        main()
    except SystemExit as exc:
        if exc.code == 1 and not _task_started:
            raise SystemExit(2) from None
        raise
