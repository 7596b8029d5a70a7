"""Testing a trained checkpoint on a data config's test set: what ``python -m spade.evaluate`` runs, and what
``also_test`` runs after a training (:func:`spade.experiments.run.test_elsewhere`)."""

from __future__ import annotations

from typing import Any

import hydra
import lightning as L
from omegaconf import DictConfig

from spade.training.instantiate import instantiate_loggers
from spade.training.loading import load_module

__all__ = ["evaluate"]


def evaluate(cfg: DictConfig) -> dict[str, Any]:
    """Test ``cfg.ckpt_path`` on ``cfg.data``'s test set; returns the test metrics."""
    from spade.experiments.checks import validate_evaluate_config

    validate_evaluate_config(cfg)  # role, and the checkpoint's window geometry against the test data's
    L.seed_everything(cfg.seed, workers=True)
    model = load_module(cfg.ckpt_path)
    datamodule = hydra.utils.instantiate(cfg.data)
    loggers = instantiate_loggers(cfg.get("logger"))
    trainer = hydra.utils.instantiate(cfg.trainer, logger=loggers or False, callbacks=[])
    results = trainer.test(model=model, datamodule=datamodule)[0]
    from spade.experiments.tracking.runs import finish_evaluation

    finish_evaluation(cfg, trainer, loggers)  # MLflow: experiment kind and description, test data input
    return {k: float(v) for k, v in results.items()}
