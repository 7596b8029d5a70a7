"""``python -m spade.train [+experiment=NAME] [key=value ...]``: train, validate and test one model.

A thin Hydra entry point in the style of lightning-hydra-template: the config (``conf/train.yaml``) composes
data, model, guidance, trainer, logger, callbacks and paths; :func:`train` builds them, resolves the run's
prerequisites (a guidance expert, a pretrained student) and returns the metrics, so that sweepers can optimise
``optimized_metric``.
"""

from __future__ import annotations

import logging
from typing import Any

import hydra
import lightning as L
from omegaconf import DictConfig, OmegaConf

import spade.paths  # noqa: F401  (registers the ${cwd:} resolver)
from spade.training.instantiate import instantiate_callbacks, instantiate_loggers, run_id_from_checkpoint
from spade.experiments.lifecycle import install_signal_handlers
from spade.experiments.validation import exit_on_user_error

log = logging.getLogger(__name__)


def train(cfg: DictConfig, _depth: int = 0) -> tuple[dict[str, Any], dict[str, Any]]:
    """Fit (and test) the configured model; returns (metrics, objects).

    In order: the config is validated (:mod:`spade.experiments.validation`: a one-line error before any MLflow run
    or data work), missing prerequisites are trained (each by a nested call), everything is re-seeded, stale
    RUNNING runs of this row are marked KILLED, and then the run itself is built and fitted. Its MLflow run ends
    KILLED (signal) or FAILED (exception) when it does not finish.
    """
    from spade.experiments.lifecycle import (
        DeterministicTraining,
        mark_run_ended,
        mark_stale_runs,
        record_process,
    )
    from spade.experiments.prerequisites import complete_prerequisite, pending_prerequisites
    from spade.experiments.tracking import finish_run, start_run_logging
    from spade.experiments.validation import validate_train_config

    validate_train_config(cfg)
    for prerequisite in pending_prerequisites(cfg, depth=_depth):
        log.info("Prerequisite %s (%s) is not registered: training it first (%s)", prerequisite.key,
                 prerequisite.name, prerequisite.command)
        train(prerequisite.config, _depth=_depth + 1)
        complete_prerequisite(cfg, prerequisite)
    seed = cfg.get("seed")
    if seed is not None:
        L.seed_everything(seed, workers=True)  # after the prerequisites: their training moved every generator
    try:
        for message in mark_stale_runs(cfg):
            print(message, flush=True)
    except Exception as exc:  # the check must not stop a run; the logger reports an unreachable store itself
        log.warning("could not check for stale RUNNING runs: %s", exc)

    log.info("Instantiating datamodule <%s>", cfg.data._target_)
    datamodule: L.LightningDataModule = hydra.utils.instantiate(cfg.data)
    log.info("Instantiating model <%s>", cfg.model._target_)
    model: L.LightningModule = hydra.utils.instantiate(cfg.model)

    ckpt_path = cfg.get("ckpt_path")
    loggers = instantiate_loggers(cfg.get("logger"), run_id=run_id_from_checkpoint(ckpt_path))
    callbacks = instantiate_callbacks(cfg.get("callbacks"))
    if seed is not None:
        callbacks.append(DeterministicTraining(seed))
    trainer: L.Trainer = hydra.utils.instantiate(cfg.trainer, callbacks=callbacks, logger=loggers or False)
    try:
        start_run_logging(cfg, model, loggers)
        record_process(loggers, resumed=bool(ckpt_path))

        baseline: dict[str, float] = {}
        if cfg.get("test_untrained", False):
            baseline = untrained_test_metrics(cfg, model, datamodule)
            for logger in loggers:
                logger.log_metrics(baseline, step=0)

        if cfg.get("train", True):
            trainer.fit(model=model, datamodule=datamodule, ckpt_path=ckpt_path)
        metrics: dict[str, Any] = {k: float(v) for k, v in trainer.callback_metrics.items() if v.numel() == 1}

        best = None
        if cfg.get("test", True):
            best = trainer.checkpoint_callback.best_model_path if trainer.checkpoint_callback else None
            best = best or None
            if best is None and cfg.get("train", True):
                log.warning("No best checkpoint found: testing the last weights")
            trainer.test(model=model, datamodule=datamodule, ckpt_path=best if best else None)
            metrics.update({k: float(v) for k, v in trainer.callback_metrics.items() if v.numel() == 1})
        metrics.update(baseline)

        finish_run(cfg, trainer, model, loggers)
    except BaseException as exc:
        mark_run_ended(loggers, exc)
        raise
    return metrics, {"cfg": cfg, "datamodule": datamodule, "model": model, "trainer": trainer, "loggers": loggers}


def untrained_test_metrics(cfg: DictConfig, model: L.LightningModule, datamodule: L.LightningDataModule) -> dict:
    """Test metrics of the model before any training, as ``untrained/...`` (the baseline learning must beat)."""
    tester = hydra.utils.instantiate(cfg.trainer, logger=False, callbacks=[], enable_progress_bar=False)
    results = tester.test(model=model, datamodule=datamodule, verbose=False)[0]
    return {k.replace("test/", "untrained/"): float(v) for k, v in results.items()}


def summary(cfg: DictConfig, metrics: dict[str, Any]) -> str:
    """The closing lines: test metrics next to the baselines, the ``mlflow ui`` command and URLs to the run and
    its experiment's runs table (:func:`spade.experiments.tracking.run_summary`)."""
    from spade.experiments.tracking import run_summary

    return run_summary(cfg, metrics)


def optimized_value(cfg: DictConfig, metrics: dict[str, Any]) -> float | None:
    """The metric a sweeper optimises, with a clear error when the run never logged it."""
    name = cfg.get("optimized_metric")
    if not name:
        return None
    if name not in metrics:
        raise KeyError(f"optimized_metric={name!r} was not logged; logged metrics: {sorted(metrics)}")
    return metrics[name]


@exit_on_user_error
def _run(cfg: DictConfig) -> float | None:
    metrics, _ = train(cfg)
    print(summary(cfg, metrics), flush=True)
    try:
        return optimized_value(cfg, metrics)
    except KeyError as exc:
        from hydra.core.hydra_config import HydraConfig
        from hydra.types import RunMode

        if HydraConfig.initialized() and HydraConfig.get().mode == RunMode.MULTIRUN:
            raise  # a sweeper needs the value
        # A single run that never validated (e.g. trainer.max_steps ended it mid-epoch) still succeeded.
        log.warning("%s", exc.args[0])
        return None


@hydra.main(version_base="1.3", config_path="../conf", config_name="train")
def main(cfg: DictConfig) -> float | None:
    log.debug("Config:\n%s", OmegaConf.to_yaml(cfg))
    install_signal_handlers()
    return _run(cfg)


if __name__ == "__main__":
    main()
