"""The SIGTERM / SIGINT that ends a run: raised in the main thread, and remembered, so that the run's record is
closed as KILLED (with the signal's name) rather than FAILED."""

from __future__ import annotations

import signal
import threading
from typing import Any

_received: dict[str, int] = {}


def signal_received() -> int | None:
    """The SIGTERM / SIGINT that is ending this process, if any."""
    return _received.get("signal")


def _on_signal(signum: int, frame: Any) -> None:
    _received.setdefault("signal", signum)
    if signum == signal.SIGINT:
        raise KeyboardInterrupt
    raise SystemExit(128 + signum)


def install_signal_handlers() -> None:
    """SIGTERM and SIGINT raise in the main thread (SystemExit / KeyboardInterrupt), so runs are closed as KILLED."""
    if threading.current_thread() is not threading.main_thread():
        return
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, _on_signal)
