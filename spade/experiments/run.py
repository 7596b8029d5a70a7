"""One training run of an experiment: what ``python -m spade.train`` does between its config and its result.

:func:`train` resolves the run's prerequisites (the margin's expert, a pretrained student:
:mod:`spade.experiments.prerequisites` returns what is missing, this module trains it), trains, validates and tests
the configured model, and returns the metrics with the objects it built; :func:`sweep_result` is the metric a
sweeper optimises. ``spade.train`` prints the closing lines from what :func:`train` returns.

Checkpoints that Lightning itself opens (``ckpt_path`` to resume a fit, the best checkpoint to test) are loaded
with ``weights_only=True`` and SPADE's allow-list (:func:`spade.models.modelfile.safe_loading`): one whose pickle
would run code is refused with :class:`~spade.models.modelfile.UnsafeModelFileError` before any of it runs.

Nothing else in ``spade/`` imports this module; it sits above :mod:`spade.experiments.prerequisites`,
``lifecycle``, :mod:`spade.config.preflight` and the training package, so no import circle runs through it. The run's MLflow
record is a callback of the run (:class:`spade.tracking.callback.RunRecord`), not code of this module.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any

import hydra
import lightning as L
from omegaconf import DictConfig, OmegaConf

from spade.experiments.lifecycle import CarryBestCheckpoint, DeterministicTraining, run_without_stages
from spade.experiments.prerequisites import Prerequisite, complete_prerequisite, pending_prerequisites
from spade.config.preflight import validate_checkpoints, validate_train_config
from spade.metrics import catalog
from spade.models.modelfile import safe_loading
from spade.training.checkpoint_paths import best_checkpoint_path, last_checkpoint_path
from spade.training.instantiate import instantiate_callbacks, instantiate_loggers, run_id_from_checkpoint
from spade.utils.console import lightning_logs_once
from spade.experiments.closed_loop_evaluation import ClosedLoopTest
from spade.experiments.evaluation import evaluate
from spade.training.teacher_labels import label_unlabelled
from spade.utils.config import compose_config
from spade.utils.console import quiet_lightning_info

__all__ = ["fit_and_test", "from_checkpoint", "optimized_value", "prerequisite_plan", "rename_prefix",
           "sweep_result", "test_elsewhere", "train", "untrained_test_metrics"]

log = logging.getLogger(__name__)


def train(cfg: DictConfig) -> tuple[dict[str, Any], dict[str, Any]]:
    """Fit (and test) the configured model; returns (metrics, objects).

    In order: the config and those of its missing prerequisites are validated and the prerequisites put in the
    order they train (:func:`prerequisite_plan`: a one-line error before any MLflow run or data work); each is
    trained (:func:`fit_and_test`) and its registered version filled into the config that needs it; then the run
    itself. Nothing here calls itself: the plan is made once, then carried out top to bottom.
    """
    lightning_logs_once()  # Lightning is loaded (this module imports it): its lines printed once, not twice
    trained: set[str] = set()
    for parent, prerequisite in prerequisite_plan(cfg):
        if prerequisite.name not in trained:  # two configs may need the same model: it trains once
            log.info("Prerequisite %s (%s) is not registered: training it first (%s)", prerequisite.key,
                     prerequisite.name, prerequisite.command)
            fit_and_test(prerequisite.config)
            trained.add(prerequisite.name)
        complete_prerequisite(parent, prerequisite)
    return fit_and_test(cfg)


def prerequisite_plan(cfg: DictConfig) -> list[tuple[DictConfig, Prerequisite]]:
    """(config that needs it, prerequisite) for every model ``cfg`` needs that is not registered, deepest first
    (a pretrained student's own expert before the student), each config validated; registered ones are filled in
    (:func:`~spade.experiments.prerequisites.pending_prerequisites`). Trains nothing."""
    validate_train_config(cfg)
    plan: list[tuple[DictConfig, Prerequisite]] = []

    planned: set[str] = set()

    def visit(config: DictConfig, depth: int) -> None:
        for prerequisite in pending_prerequisites(config, depth=depth):
            if prerequisite.name not in planned:
                validate_train_config(prerequisite.config)
                visit(prerequisite.config, depth + 1)
                planned.add(prerequisite.name)
            plan.append((config, prerequisite))

    visit(cfg, 0)
    return plan


def fit_and_test(cfg: DictConfig) -> tuple[dict[str, Any], dict[str, Any]]:
    """One run whose prerequisites are filled in: checkpoints checked, everything re-seeded, then data, model,
    trainer, fit, test. The run's MLflow record (its opening, status and end) is kept by a callback of the run,
    built from the callbacks config with this config (:class:`spade.tracking.callback.RunRecord`); the objects
    returned carry the checkpoint the run ends with (``checkpoint``: its best, else its last; "" without one) and
    where the run lives (``run``: None without an MLflow logger)."""
    validate_checkpoints(cfg)  # a model fetched from the registry passes the checks of one given by path
    seed = cfg.get("seed")
    if seed is not None:
        L.seed_everything(seed, workers=True)  # after the prerequisites: their training moved every generator

    log.info("Instantiating datamodule <%s>", cfg.data._target_)
    datamodule: L.LightningDataModule = hydra.utils.instantiate(cfg.data)
    if getattr(datamodule, "teacher_label_request", lambda: None)() is not None:
        label_unlabelled(datamodule)  # a teacher's plans label the unsketched states (sampled once, then read)
    log.info("Instantiating model <%s>", cfg.model._target_)
    model: L.LightningModule = hydra.utils.instantiate(cfg.model)

    ckpt_path = cfg.get("ckpt_path")
    loggers = instantiate_loggers(cfg.get("logger"), run_id=run_id_from_checkpoint(ckpt_path))
    callbacks = instantiate_callbacks(cfg.get("callbacks"), run_cfg=cfg)
    if seed is not None:
        callbacks.append(DeterministicTraining(seed))
    if ckpt_path and cfg.get("train", True):
        callbacks.append(CarryBestCheckpoint(str(ckpt_path)))  # the interrupted run's best stays the best
    drive = None
    if cfg.get("closed_loop") and type(model).__name__ == "StudentModule":  # the best checkpoint, after the test
        drive = ClosedLoopTest(OmegaConf.to_container(cfg.drive, resolve=True), int(cfg.get("seed") or 0))
        callbacks.append(drive)
    trainer: L.Trainer = hydra.utils.instantiate(cfg.trainer, callbacks=callbacks, logger=loggers or False)

    baseline: dict[str, float] = {}
    if cfg.get("test_untrained", False):
        baseline = untrained_test_metrics(cfg, model, datamodule)
        for logger in loggers:
            logger.log_metrics(baseline, step=0)

    if cfg.get("train", True):
        from_checkpoint(trainer.fit, ckpt_path, model=model, datamodule=datamodule)
    metrics: dict[str, Any] = {k: float(v) for k, v in trainer.callback_metrics.items() if v.numel() == 1}

    if cfg.get("test", True):
        best = best_checkpoint_path(trainer) or None
        if best is None and cfg.get("train", True):
            log.warning("No best checkpoint found: testing the last weights")
        # verbose=False: Lightning's table of every figure, unrounded (over a hundred lines), buried the summary
        # spade.train prints from these metrics (spade.tracking.summary.run_summary)
        from_checkpoint(trainer.test, best, model=model, datamodule=datamodule, verbose=False)
        metrics.update({k: float(v) for k, v in trainer.callback_metrics.items() if v.numel() == 1})
        metrics.update(drive.metrics if drive is not None else {})
        for name, data in (cfg.get("also_test") or {}).items():
            metrics.update(test_elsewhere(cfg, best or last_checkpoint_path(trainer), name, data))
    elif not cfg.get("train", True):
        run_without_stages(trainer, model)  # no stage: the callbacks' setup and teardown, the loggers closed
    metrics.update(baseline)
    return metrics, {"cfg": cfg, "datamodule": datamodule, "model": model, "trainer": trainer, "loggers": loggers,
                     "checkpoint": best_checkpoint_path(trainer) or last_checkpoint_path(trainer),
                     "run": next((cb.run for cb in callbacks if hasattr(cb, "run")), None)}


def test_elsewhere(cfg: DictConfig, ckpt_path: str, name: str, data: str) -> dict[str, float]:
    """Test the run's best checkpoint on another data config's test set (``also_test: {NAME: DATA}``, e.g.
    ``{real: realmap_L}``: maps no training set uses) as ``python -m spade.evaluate`` does, in a run of its own named
    ``<run_name>_<NAME>`` in the same MLflow experiment, carrying the run's seed (so that ``spade.report`` counts it
    per seed, like a row). Returns its metrics as ``<NAME>/test/...``."""
    overrides = [f"ckpt_path={ckpt_path}", f"data={data}", f"scale={cfg.scale.name}", f"recipe={cfg.recipe.name}", f"run_name={cfg.run_name}_{name}",
                 f"tags.table={cfg.tags.table}", f"tags.row={cfg.run_name}_{name}", f"seed={cfg.seed}",
                 f"source_seed={cfg.seed}", f"paths.output_dir={cfg.paths.output_dir}/{name}",
                 f"trainer.enable_progress_bar={bool(cfg.trainer.get('enable_progress_bar', True))}"]
    if OmegaConf.select(cfg, "logger.mlflow") is None:
        overrides.append("logger=none")
    results = evaluate(compose_config("evaluate", overrides))
    headline = {catalog.mlflow_key(n) for n in catalog.HEADLINE}
    print(f"  {name} ({data}): " + "  ".join(f"{k.split('/', 1)[1]}={catalog.fmt(k, v)}"
                                            for k, v in sorted(results.items()) if k in headline), flush=True)
    return {f"{name}/{k}": v for k, v in results.items()}


def from_checkpoint(step: Callable[..., Any], ckpt_path: str | Path | None, **kwargs: Any) -> Any:
    """``step(ckpt_path=ckpt_path, **kwargs)``, a ``Trainer``'s ``fit`` (resume) or ``test`` (those weights), with
    Lightning's load of the checkpoint made safe: ``weights_only=True`` and SPADE's allow-list
    (:func:`spade.models.modelfile.safe_loading`; a pickle that would run code raises ``UnsafeModelFileError``)."""
    with safe_loading(ckpt_path or ""):
        return step(ckpt_path=ckpt_path, weights_only=True, **kwargs)


def untrained_test_metrics(cfg: DictConfig, model: L.LightningModule, datamodule: L.LightningDataModule) -> dict:
    """Test metrics of the model before any training, as ``untrained/...`` (the baseline learning must beat)."""
    with quiet_lightning_info():  # the run's trainer has said which devices it uses; this one would say it again
        tester = hydra.utils.instantiate(cfg.trainer, logger=False, callbacks=[], enable_progress_bar=False)
        results = tester.test(model=model, datamodule=datamodule, verbose=False)[0]
    return rename_prefix({k: float(v) for k, v in results.items()}, "test/", "untrained/")


def rename_prefix(metrics: dict[str, float], old: str, new: str) -> dict[str, float]:
    """``metrics`` with the leading ``old`` of each key replaced by ``new`` (only there: ``test/baseline/shortest/``
    stays ``shortest``)."""
    return {new + k[len(old):] if k.startswith(old) else k: v for k, v in metrics.items()}


def sweep_result(cfg: DictConfig, metrics: dict[str, Any]) -> float | None:
    """``optimized_metric``'s value (:func:`optimized_value`), what ``spade.train`` hands to Hydra's sweeper.

    A single run that never logged that metric (e.g. ``trainer.max_steps`` ended it before a validation) still
    succeeded: the missing metric is a warning and the result ``None``; under a Hydra multirun it is an error,
    since the sweeper needs the value.
    """
    try:
        return optimized_value(cfg, metrics)
    except KeyError as exc:
        from hydra.core.hydra_config import HydraConfig
        from hydra.types import RunMode

        if HydraConfig.initialized() and HydraConfig.get().mode == RunMode.MULTIRUN:
            raise  # a sweeper needs the value
        log.warning("%s", exc.args[0])
        return None


def optimized_value(cfg: DictConfig, metrics: dict[str, Any]) -> float | None:
    """The metric a sweeper optimises, with a clear error when the run never logged it."""
    name = cfg.get("optimized_metric")
    if not name:
        return None
    if name not in metrics:
        raise KeyError(f"optimized_metric={name!r} was not logged; logged metrics: {sorted(metrics)}")
    return metrics[name]
