"""A training run's MLflow record, kept by one Lightning callback: :class:`RunRecord`.

``conf/callbacks/default.yaml`` lists it (``run_record``); ``spade.train`` gives it the run's composed config when
it builds the callbacks. Without an MLflow logger it does nothing. Its hooks, in the order Lightning calls them:

* ``setup`` (the first stage): stale RUNNING runs of the row marked KILLED (:func:`~spade.tracking.runs.
  mark_stale_runs`), the run's experiment tagged (:func:`~spade.tracking.runs.bind_experiment`), its process
  recorded, its parameters, config and the model's parameter count logged.
* ``on_test_end``: the classical baselines and the untrained model as child runs (:mod:`~spade.tracking.predictors`).
* ``teardown`` of the run's last stage (the test, else the fit), before the logger closes the run: the best and
  last checkpoints, the training-progress picture (:mod:`~spade.tracking.progress_picture`), a student's best
  checkpoint as the run's MLflow Model (:mod:`~spade.tracking.logged_model`), the datasets as inputs, the
  description and the report, the process tags dropped, and the checkpoint registered when the row asks
  (:mod:`~spade.tracking.registry`). Between a fit and its test the run is held open (SPADE's logger,
  :mod:`~spade.tracking.logger`), so nothing is written into a closed run.
* ``on_exception``: the run marked KILLED (a signal, Ctrl+C) or FAILED, with the reason.

A run that trains and tests nothing (``train=false test=false``) gets the same ``setup`` and ``teardown`` from
:func:`spade.experiments.lifecycle.run_without_stages`, with stage ``"none"``: it is opened, completed and closed
FINISHED like any other.

Where the finished run lives (:class:`~spade.tracking.runs.RunRef`) is :attr:`RunRecord.run` afterwards.
"""

from __future__ import annotations

import logging
from typing import Any

import lightning as L
from lightning.pytorch.callbacks import Callback
from omegaconf import DictConfig

from spade.tracking.runs import (
    RunRef,
    bind_experiment,
    describe_run,
    drop_process_tags,
    log_predictors,
    log_report,
    log_run_config,
    mark_opened_run_ended,
    mark_stale_runs,
    mlflow_logger,
    nicety,
    record_process,
    run_figures,
)

log = logging.getLogger(__name__)

NO_STAGE = "none"  # the stage of a run that trains and tests nothing (its callbacks' setup and teardown)


class RunRecord(Callback):
    """The run's MLflow record from its first stage to its last (see the module)."""

    def __init__(self, cfg: DictConfig | None = None) -> None:
        self.cfg = cfg
        self.run: RunRef | None = None  # where the run lives, once its record is complete
        self._opened = False
        self._predictors_logged = False

    def _logger(self, trainer: L.Trainer) -> Any:
        """The run's MLflow logger on rank zero; None without one, on other ranks, or without a config."""
        if self.cfg is None or not trainer.is_global_zero:
            return None
        return mlflow_logger(trainer.loggers)

    def _last_stage(self) -> str:
        """The stage whose teardown completes the record: the test, else the fit, else none (see the module)."""
        if self.cfg.get("test", True):
            return "test"
        return "fit" if self.cfg.get("train", True) else NO_STAGE

    # -- the run's start ---------------------------------------------------------------------------------------------
    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        ml = self._logger(trainer)
        if ml is None or self._opened:
            return
        self._opened = True
        self.open(ml, pl_module)
        if stage != self._last_stage() and hasattr(ml, "hold_open"):
            ml.hold_open = True  # the fit's end leaves the run open for the test

    def open(self, ml: Any, model: Any) -> None:
        """Bind the run and record its start: stale runs of the row closed, experiment tagged, process, config,
        parameters and the model's parameter count."""
        cfg = self.cfg
        try:
            for message in mark_stale_runs(cfg):
                print(message, flush=True)
        except Exception as exc:  # noqa: BLE001 - the check must not stop a run
            log.warning("could not check for stale RUNNING runs: %s", exc)
        bind_experiment(ml, cfg)
        record_process([ml], resumed=bool(cfg.get("ckpt_path")))
        log_run_config(cfg, model, ml)

    # -- the test's references ---------------------------------------------------------------------------------------
    def on_test_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        ml = self._logger(trainer)
        if ml is None:
            return
        from spade.tracking.dataset_inputs import dataset_uses

        datamodule = getattr(trainer, "datamodule", None)
        uses = [u for u in (dataset_uses(datamodule) if datamodule is not None else []) if u.context == "test"]
        log_predictors(self.cfg, ml.experiment, ml.run_id, uses, run_figures(ml))
        self._predictors_logged = True

    # -- the run's end -----------------------------------------------------------------------------------------------
    def teardown(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        ml = self._logger(trainer)
        if ml is None or stage != self._last_stage():
            return
        self.finish(trainer, ml)
        if hasattr(ml, "hold_open"):
            ml.hold_open = False  # the logger's finalize, next, closes the run

    def finish(self, trainer: L.Trainer, ml: Any) -> None:
        """Complete the record of a run whose last stage ended (see the module); sets :attr:`run`."""
        from spade.experiments.lifecycle import best_checkpoint_path, last_checkpoint_path
        from spade.tracking.logged_model import try_log_student_model

        cfg = self.cfg
        client, run_id = ml.experiment, ml.run_id
        paths = {kind: path for kind, path in (("best", best_checkpoint_path(trainer)),
                                               ("last", last_checkpoint_path(trainer))) if path}
        for kind, path in paths.items():
            client.log_artifact(run_id, path, artifact_path=f"checkpoints/{kind}")
        if cfg.get("train", True):
            from spade.tracking.progress_picture import log_progress_picture

            nicety("training-progress picture", log_progress_picture, client, run_id,
                   f"{cfg.get('run_name')}: training by epoch")
        logged = try_log_student_model(cfg, str(client.tracking_uri), run_id, paths.get("best") or paths.get("last"))
        uses, metrics, description, self.run = describe_run(cfg, ml, getattr(trainer, "datamodule", None),
                                                            logged_model=logged)
        if not self._predictors_logged:  # no test: the run is still tagged with its role
            log_predictors(cfg, client, run_id, [], metrics)
        log_report(cfg, client, run_id, description, metrics)
        nicety("process tags' removal", drop_process_tags, client, run_id, True)
        if paths:
            self.register(ml, "best" if "best" in paths else "last", uses, metrics)

    def register(self, ml: Any, kind: str, uses: list[Any], metrics: dict[str, float]) -> None:
        """Register ``checkpoints/<kind>`` when the row asks (``registry.prefix``)."""
        from spade.tracking.descriptions import model_description, version_description
        from spade.tracking.registry import data_fingerprint, register_checkpoint, registry_name

        cfg = self.cfg
        name = registry_name(cfg)
        if not name:
            return
        tags = {**dict(cfg.get("tags") or {}), **dict((cfg.get("registry") or {}).get("tags") or {})}
        register_checkpoint(ml, name, f"checkpoints/{kind}", tags=tags, data_fingerprint=data_fingerprint(cfg),
                            description=model_description(cfg, uses),
                            version_description=version_description(cfg, ml, metrics),
                            promote=bool((cfg.get("registry") or {}).get("promote", False)))

    # -- a run that does not finish ----------------------------------------------------------------------------------
    def on_exception(self, trainer: L.Trainer, pl_module: L.LightningModule, exception: BaseException) -> None:
        ml = self._logger(trainer)
        if ml is None:
            return
        status = mark_opened_run_ended([ml], exception)  # also a run Lightning opened before setup bound it
        if status is not None and hasattr(ml, "end_status"):
            ml.end_status = status  # Lightning's finalize("failed"), next, keeps it
            ml.hold_open = False
