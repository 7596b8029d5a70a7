"""A callback that signals its own training process at a given batch: kills in tests come from here, not sleeps.

A ``spade.train`` subprocess takes it as extra overrides (:func:`kill_at`) with ``tests/`` on its ``PYTHONPATH``
(:func:`env_with_tests`): the kill then lands exactly at that batch, however loaded the machine is.
"""

from __future__ import annotations

import os
import signal as signals
from pathlib import Path

from lightning import Callback

TESTS = Path(__file__).resolve().parent


class SignalAt(Callback):
    """Send ``signal`` (a name: SIGKILL, SIGTERM ...) to this process when batch ``batch`` of epoch ``epoch``
    starts (0-based; batches ``0 .. batch - 1`` of that epoch are done and logged). A process that leads its own
    group (``start_new_session=True``) signals the whole group, as ``kill -9 -PGID`` from outside would."""

    def __init__(self, epoch: int, batch: int, signal: str = "SIGKILL") -> None:
        self.epoch, self.batch, self.signal = int(epoch), int(batch), getattr(signals, str(signal))

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx: int) -> None:
        if trainer.current_epoch == self.epoch and batch_idx == self.batch:
            if os.getpgrp() == os.getpid():
                os.killpg(os.getpgrp(), self.signal)
            else:
                os.kill(os.getpid(), self.signal)


def kill_at(epoch: int, batch: int, sig: str = "SIGKILL") -> list[str]:
    """The ``spade.train`` overrides that add :class:`SignalAt` to a run's callbacks."""
    return ["+callbacks.signal_at._target_=fault_injection.SignalAt", f"+callbacks.signal_at.epoch={epoch}",
            f"+callbacks.signal_at.batch={batch}", f"+callbacks.signal_at.signal={sig}"]


def env_with_tests(env: dict[str, str]) -> dict[str, str]:
    """``env`` with ``tests/`` on ``PYTHONPATH``, so that a subprocess can import this module."""
    path = env.get("PYTHONPATH")
    return {**env, "PYTHONPATH": str(TESTS) + (os.pathsep + path if path else "")}
