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


class FailAt(Callback):
    """Raise ``RuntimeError("injected failure ...")`` when batch ``batch`` of epoch ``epoch`` starts: a crash at a
    known place, in-process (the run ends FAILED, its epoch-end checkpoints stay)."""

    def __init__(self, epoch: int, batch: int) -> None:
        self.epoch, self.batch = int(epoch), int(batch)

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx: int) -> None:
        if trainer.current_epoch == self.epoch and batch_idx == self.batch:
            raise RuntimeError(f"injected failure at epoch {self.epoch}, batch {self.batch}")


def fail_at(epoch: int, batch: int) -> list[str]:
    """The ``spade.train`` overrides that add :class:`FailAt` to a run's callbacks."""
    return ["+callbacks.fail_at._target_=fault_injection.FailAt", f"+callbacks.fail_at.epoch={epoch}",
            f"+callbacks.fail_at.batch={batch}"]
