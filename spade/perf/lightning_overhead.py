"""What Lightning adds to a training step: the same BC step of a student timed inside ``Trainer.fit`` (logging
every N steps to a CSV logger, with or without the progress bar) and as a bare loop, in the same rounds."""

from __future__ import annotations

import contextlib
import io
import statistics
import tempfile
import time
from collections.abc import Sequence
from typing import Any

import lightning as L
import torch
from lightning.pytorch.callbacks import Callback, TQDMProgressBar
from lightning.pytorch.loggers import CSVLogger
from spade.perf.training import LEVERS, build_step, example_batch, Setup
from spade.training.student_module import StudentModule


class _StepClock(Callback):
    """Wall time between successive training-batch starts: one whole step as the trainer runs it."""

    def __init__(self) -> None:
        self.starts: list[float] = []

    def on_train_batch_start(self, *args: Any) -> None:
        self.starts.append(time.perf_counter())

    def step_ms(self) -> list[float]:
        return [(b - a) * 1000.0 for a, b in zip(self.starts[1:], self.starts[2:])]  # the first step warms up


def _fit_step_ms(student: str, batches: list[dict[str, torch.Tensor]], log_every_n_steps: int,
                 progress_bar: bool) -> list[float]:
    """Per-step ms of ``Trainer.fit`` over ``batches`` (no validation, no checkpoints)."""
    clock = _StepClock()
    callbacks: list[Callback] = [clock]
    if progress_bar:
        callbacks.append(TQDMProgressBar(refresh_rate=1))
    with tempfile.TemporaryDirectory() as tmp, contextlib.redirect_stderr(io.StringIO()):
        trainer = L.Trainer(accelerator="cpu", devices=1, max_steps=len(batches), logger=CSVLogger(tmp),
                            log_every_n_steps=log_every_n_steps, enable_progress_bar=progress_bar,
                            enable_checkpointing=False, enable_model_summary=False, limit_val_batches=0,
                            num_sanity_val_steps=0, callbacks=callbacks, default_root_dir=tmp)
        loader = torch.utils.data.DataLoader(batches, batch_size=None)
        trainer.fit(StudentModule(size=student), train_dataloaders=loader)
    return clock.step_ms()


def lightning_overhead(student: str, image_size: int, batch_size: int, steps: int, rounds: int,
                       settings: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per-step ms of a bare BC loop and of ``Trainer.fit`` under each setting (``log_every_n_steps``,
    ``progress_bar``), ``rounds`` times in turn; each row with its difference to the bare loop."""
    batch = example_batch(batch_size, image_size)
    batches = [dict(batch) for _ in range(steps + 2)]
    bare = build_step(Setup("BC", student), LEVERS["baseline"], batch)
    bare()
    times: dict[str, list[float]] = {"bare loop": []}
    for s in settings:
        times[s["name"]] = []
    for _ in range(rounds):
        for _ in range(steps):
            t0 = time.perf_counter()
            bare()
            times["bare loop"].append((time.perf_counter() - t0) * 1000.0)
        for s in settings:
            times[s["name"]] += _fit_step_ms(student, batches, int(s["log_every_n_steps"]), bool(s["progress_bar"]))
    base = statistics.median(times["bare loop"])
    rows = [{"setting": "bare loop", "log_every_n_steps": None, "progress_bar": False, "step_ms": base,
             "overhead_ms": 0.0, "steps": len(times["bare loop"])}]
    for s in settings:
        ms = statistics.median(times[s["name"]])
        rows.append({"setting": s["name"], "log_every_n_steps": int(s["log_every_n_steps"]),
                     "progress_bar": bool(s["progress_bar"]), "step_ms": ms, "overhead_ms": ms - base,
                     "steps": len(times[s["name"]])})
    return rows
