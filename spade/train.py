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
from lightning.pytorch.loggers import MLFlowLogger
from omegaconf import DictConfig, OmegaConf

import spade.paths  # noqa: F401  (registers the ${cwd:} resolver)
from spade.training.instantiate import instantiate_callbacks, instantiate_loggers, run_id_from_checkpoint

log = logging.getLogger(__name__)


def train(cfg: DictConfig) -> tuple[dict[str, Any], dict[str, Any]]:
    """Fit (and test) the configured model; returns (metrics, objects)."""
    from spade.experiments.prerequisites import resolve_prerequisites
    from spade.experiments.tracking import finish_run, start_run_logging

    if cfg.get("seed") is not None:
        L.seed_everything(cfg.seed, workers=True)
    resolve_prerequisites(cfg)

    log.info("Instantiating datamodule <%s>", cfg.data._target_)
    datamodule: L.LightningDataModule = hydra.utils.instantiate(cfg.data)
    log.info("Instantiating model <%s>", cfg.model._target_)
    model: L.LightningModule = hydra.utils.instantiate(cfg.model)

    ckpt_path = cfg.get("ckpt_path")
    loggers = instantiate_loggers(cfg.get("logger"), run_id=run_id_from_checkpoint(ckpt_path))
    callbacks = instantiate_callbacks(cfg.get("callbacks"))
    trainer: L.Trainer = hydra.utils.instantiate(cfg.trainer, callbacks=callbacks, logger=loggers or False)
    start_run_logging(cfg, model, loggers)

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
    return metrics, {"cfg": cfg, "datamodule": datamodule, "model": model, "trainer": trainer, "loggers": loggers}


def untrained_test_metrics(cfg: DictConfig, model: L.LightningModule, datamodule: L.LightningDataModule) -> dict:
    """Test metrics of the model before any training, as ``untrained/...`` (the baseline learning must beat)."""
    tester = hydra.utils.instantiate(cfg.trainer, logger=False, callbacks=[], enable_progress_bar=False)
    results = tester.test(model=model, datamodule=datamodule, verbose=False)[0]
    return {k.replace("test/", "untrained/"): float(v) for k, v in results.items()}


def summary(cfg: DictConfig, metrics: dict[str, Any]) -> str:
    """The closing lines: test metrics (and the untrained baseline) and how to open the run in the MLflow UI."""
    keys = ("ape_cm", "fid", "hd19", "failure_rate", "seconds_per_sample")
    lines = [f"run {cfg.get('run_name')} finished"]
    for prefix in ("test", "untrained"):
        vals = [f"{k}={metrics[f'{prefix}/{k}']:.4g}" for k in keys if f"{prefix}/{k}" in metrics]
        if vals:
            lines.append(f"  {prefix:9s}: " + "  ".join(vals))
    uri = cfg.paths.mlflow_tracking_uri
    if str(uri).startswith(("http://", "https://")):
        lines.append(f"open the MLflow UI on it at:  {uri}")
    else:
        lines.append(f"open the MLflow UI on it with:  mlflow ui --backend-store-uri {uri}")
    return "\n".join(lines)


def optimized_value(cfg: DictConfig, metrics: dict[str, Any]) -> float | None:
    """The metric a sweeper optimises, with a clear error when the run never logged it."""
    name = cfg.get("optimized_metric")
    if not name:
        return None
    if name not in metrics:
        raise KeyError(f"optimized_metric={name!r} was not logged; logged metrics: {sorted(metrics)}")
    return metrics[name]


@hydra.main(version_base="1.3", config_path="../conf", config_name="train")
def main(cfg: DictConfig) -> float | None:
    log.debug("Config:\n%s", OmegaConf.to_yaml(cfg))
    metrics, _ = train(cfg)
    print(summary(cfg, metrics), flush=True)
    return optimized_value(cfg, metrics)


if __name__ == "__main__":
    main()
