"""Where a Lightning run's checkpoints are: its newest epoch-end one and its best by the monitored metric."""

from __future__ import annotations

import lightning as L


def last_checkpoint_path(trainer: L.Trainer) -> str:
    """The run's newest epoch-end checkpoint (``checkpoints/last.ckpt``), ``""`` when none was written.

    ``conf/callbacks/default.yaml`` writes it with a second, unmonitored ``ModelCheckpoint`` (``last_checkpoint``),
    whose only checkpoint is its ``best_model_path``; a config that uses ``save_last`` instead has it as
    ``last_model_path``.
    """
    for cb in trainer.checkpoint_callbacks:
        if getattr(cb, "last_model_path", ""):
            return str(cb.last_model_path)
        if getattr(cb, "monitor", "unset") is None and getattr(cb, "best_model_path", ""):
            return str(cb.best_model_path)
    return ""


def best_checkpoint_path(trainer: L.Trainer) -> str:
    """The run's best checkpoint by its monitored metric (the first ``ModelCheckpoint``'s), ``""`` when none."""
    callback = trainer.checkpoint_callback
    return str(callback.best_model_path or "") if callback is not None else ""
