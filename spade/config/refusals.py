"""How the entry points report a user error: one line on stderr and exit status 2 (``HYDRA_FULL_ERROR=1`` shows
the traceback instead). Every user error derives from :class:`spade.utils.errors.UserError`;
:class:`~spade.utils.errors.ConfigError` is the one these checks raise."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from spade.utils.errors import ConfigError, UserError, exit_on_errors

__all__ = ["ConfigError", "UserError", "exit_on_user_error", "user_errors"]


def user_errors() -> tuple[type[BaseException], ...]:
    """Exceptions that mean the user must change something (reported without a traceback): every package's user
    errors derive from :class:`spade.utils.errors.UserError`."""
    return (UserError,)


def exit_on_user_error(fn: Callable[..., Any]) -> Callable[..., Any]:
    """Wrap an entry point's task function: a user error (:func:`user_errors`) ends the process with one line and
    exit status 2.

    ``HYDRA_FULL_ERROR=1`` re-raises it instead, for Hydra's full traceback.
    """
    return exit_on_errors(user_errors)(fn)
