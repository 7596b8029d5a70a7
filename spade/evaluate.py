"""``python -m spade.evaluate ckpt_path=PATH [data=...]``: test a trained student or expert on a test set."""

from __future__ import annotations

import logging
from typing import Any

import hydra
import lightning as L
from omegaconf import DictConfig

import spade.paths  # noqa: F401  (registers the ${cwd:} resolver)
from spade.training.instantiate import instantiate_loggers
from spade.training.loading import load_module

__all__ = ["evaluate", "load_module"]

log = logging.getLogger(__name__)


def evaluate(cfg: DictConfig) -> dict[str, Any]:
    """Test ``cfg.ckpt_path`` on ``cfg.data``'s test set; returns the test metrics."""
    from spade.experiments.config_checks import validate_evaluate_config

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


@hydra.main(version_base="1.3", config_path="../conf", config_name="evaluate")
def main(cfg: DictConfig) -> None:
    from spade.experiments.config_checks import exit_on_user_error

    metrics = exit_on_user_error(evaluate)(cfg)
    print("\n".join(f"{k}: {v:.4g}" for k, v in sorted(metrics.items())))


if __name__ == "__main__":
    main()
