"""A run's MLflow record, kept by one Lightning callback: :class:`RunRecord`, for ``spade.train`` and
``spade.evaluate`` alike.

``conf/callbacks/default.yaml`` lists it (``run_record``); ``spade.train`` gives it the run's composed config when
it builds the callbacks, ``spade.evaluate`` builds it itself. What it logs beyond the run's own objects comes from
the run's :class:`RunIdentity` (experiment, run name, tags, parameters, stages), made once from the config
(:func:`training_identity`, :func:`evaluation_identity`); the config itself feeds what describes the run (its
description, ``config/train.yaml``, the logged and registered model). Without an MLflow logger it does nothing. Its hooks, in the order Lightning calls them:

* ``setup`` (the first stage): the run's experiment tagged (:func:`~spade.tracking.runs.bind_experiment`) and its
  parameters logged; a training run also has the stale RUNNING runs of its row marked KILLED
  (:func:`~spade.tracking.runs.mark_stale_runs`), its process recorded and its config logged. The run is kept
  open (:meth:`~spade.tracking.logger.MLFlowLogger.keep_open`) until its last stage's ``teardown``.
* ``on_test_end``: the classical baselines and the untrained model as child runs (:mod:`~spade.tracking.predictors`);
  logged again when the run's record is completed if figures for them came later (a closed loop driven after the
  test: :class:`~spade.experiments.closed_loop_evaluation.ClosedLoopTest`, whichever callback's hook runs first).
* ``teardown`` of the run's last stage (the test, else the fit), which then closes the run: a training run's best and
  last checkpoints, the training-progress picture (:mod:`~spade.tracking.progress_picture`), a student's best
  checkpoint as the run's MLflow Model (:mod:`~spade.tracking.logged_model`), the datasets as inputs, the
  description and the report, the process tags dropped, and the checkpoint registered when the row asks
  (:mod:`~spade.tracking.registry`); an evaluation's, its test data as input, the description and the
  report.
* ``on_exception``: the run marked KILLED (a signal, Ctrl+C) or FAILED, with the reason.

A run that trains and tests nothing (``train=false test=false``) gets the same ``setup`` and ``teardown`` from
:func:`spade.experiments.lifecycle.run_without_stages`, with stage ``"none"``: it is opened, completed and closed
FINISHED like any other.

Where the finished run lives (:class:`~spade.tracking.runs.RunRef`) is :attr:`RunRecord.run` afterwards.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import lightning as L
from lightning.pytorch.callbacks import Callback
from omegaconf import DictConfig, OmegaConf

from spade.tracking.params import run_params
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
from spade.tracking.dataset_inputs import dataset_uses
from spade.tracking.predictors import predictor_figures
from spade.tracking.descriptions import model_description, version_description
from spade.tracking.logged_model import try_log_student_model
from spade.tracking.progress_picture import log_progress_picture
from spade.tracking.registry import data_fingerprint, register_checkpoint, registry_name
from spade.training.checkpoint_paths import best_checkpoint_path, last_checkpoint_path

log = logging.getLogger(__name__)

NO_STAGE = "none"  # the stage of a run that trains and tests nothing (its callbacks' setup and teardown)
EXPERT_SAMPLING = ("sampler", "num_inference_steps", "test_samples", "guidance_scale")  # an evaluated expert's


@dataclass(frozen=True)
class RunIdentity:
    """Who a run is, as its record logs it: where it goes, its tags and parameters, the stages it runs."""

    experiment: str
    run_name: str
    tags: Mapping[str, Any] = field(default_factory=dict)
    params: Mapping[str, Any] = field(default_factory=dict)  # cfg/<group>/<key>: value
    stages: tuple[str, ...] = ("fit", "test")  # in the order they run; () for a run with no stage
    training: bool = True  # spade.train's: stale runs, process, config, checkpoints, model and registry recorded
    resumed: bool = False  # a resumed training run (ckpt_path): RUNNING again

    @property
    def last_stage(self) -> str:
        """The stage whose teardown completes the record (:data:`NO_STAGE` without one)."""
        return self.stages[-1] if self.stages else NO_STAGE

    @property
    def role(self) -> str:
        return str(self.tags.get("role") or "model")


def run_identity(cfg: DictConfig, params: Mapping[str, Any], stages: tuple[str, ...] = (), training: bool = False,
                 resumed: bool = False) -> RunIdentity:
    """``cfg``'s run (its MLflow experiment, run name and tags) with ``params`` and ``stages``."""
    tags = dict(OmegaConf.to_container(cfg.tags, resolve=True)) if cfg.get("tags") is not None else {}
    experiment = OmegaConf.select(cfg, "logger.mlflow.experiment_name", default=None) or tags.get("table") or ""
    return RunIdentity(str(experiment), str(cfg.get("run_name") or "run"), tags, dict(params), stages, training,
                       resumed)


def training_identity(cfg: DictConfig) -> RunIdentity:
    """``spade.train``'s run: its parameters by group (:func:`~spade.tracking.params.run_params`), its stages."""
    train, test = bool(cfg.get("train", True)), bool(cfg.get("test", True))
    stages = tuple(stage for stage, runs in (("fit", train), ("test", test)) if runs)
    return run_identity(cfg, run_params(OmegaConf.to_container(cfg, resolve=True)), stages, training=True,
                        resumed=bool(cfg.get("ckpt_path")))


def evaluation_identity(cfg: DictConfig, tested: bool = True) -> RunIdentity:
    """``spade.evaluate``'s run: a training run's checkpoint tested elsewhere counts under that run's seed
    (``cfg/seed``); without ``tested`` (closed loop only) no stage runs."""
    params = {"cfg/seed": int(cfg.source_seed)} if cfg.get("source_seed") is not None else {}
    return run_identity(cfg, params, ("test",) if tested else ())


class RunRecord(Callback):
    """The run's MLflow record from its first stage to its last (see the module)."""

    def __init__(self, cfg: DictConfig | None = None, identity: RunIdentity | None = None) -> None:
        self.cfg = cfg
        self.identity = identity if identity is not None or cfg is None else training_identity(cfg)
        self.run: RunRef | None = None  # where the run lives, once its record is complete
        self._opened = False
        self._predictors_logged: dict[str, list[str]] | None = None  # the child runs' figures, once logged

    def _logger(self, trainer: L.Trainer) -> Any:
        """The run's MLflow logger on rank zero; None without one, on other ranks, or without a config."""
        if self.cfg is None or self.identity is None or not trainer.is_global_zero:
            return None
        return mlflow_logger(trainer.loggers)

    # -- the run's start ---------------------------------------------------------------------------------------------
    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        ml = self._logger(trainer)
        if ml is None or self._opened:
            return
        self._opened = True
        self.open(ml, pl_module)
        if hasattr(ml, "keep_open"):
            ml.keep_open()  # the end of a stage leaves the run open: its last stage's teardown closes it

    def open(self, ml: Any, model: Any) -> None:
        """Bind the run and record its start: experiment tagged, parameters; a training run's stale runs closed,
        process, config and the model's parameter count."""
        cfg, identity = self.cfg, self.identity
        if not identity.training:
            bind_experiment(ml, cfg)
            hparams = getattr(model, "hparams", None) or {}
            sampling = {f"cfg/model/{k}": hparams[k] for k in EXPERT_SAMPLING if k in hparams}
            for key, value in {**identity.params, **sampling}.items():
                ml.experiment.log_param(ml.run_id, key, value)
            return
        try:
            for message in mark_stale_runs(cfg):
                print(message, flush=True)
        except Exception as exc:  # noqa: BLE001 - the check must not stop a run
            log.warning("could not check for stale RUNNING runs: %s", exc)
        bind_experiment(ml, cfg)
        record_process([ml], resumed=identity.resumed)
        log_run_config(cfg, dict(identity.params), model, ml)

    # -- the test's references ---------------------------------------------------------------------------------------
    def on_test_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        ml = self._logger(trainer)
        if ml is None:
            return
        datamodule = getattr(trainer, "datamodule", None)
        uses = [u for u in (dataset_uses(datamodule) if datamodule is not None else []) if u.context == "test"]
        metrics = run_figures(ml)
        log_predictors(self.identity.tags, ml.experiment, ml.run_id, uses, metrics)
        self._predictors_logged = predictor_figures(metrics)

    # -- the run's end -----------------------------------------------------------------------------------------------
    def teardown(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        ml = self._logger(trainer)
        if ml is None or stage != self.identity.last_stage:
            return
        self.finish(trainer, ml)
        if hasattr(ml, "close"):
            ml.close("success")  # the record is complete: the run ends

    def finish(self, trainer: L.Trainer, ml: Any) -> None:
        """Complete the record of a run whose last stage ended (see the module); sets :attr:`run`."""
        cfg, identity = self.cfg, self.identity
        client, run_id = ml.experiment, ml.run_id
        datamodule = getattr(trainer, "datamodule", None)
        if not identity.training:
            uses, metrics, description, self.run = describe_run(cfg, ml, datamodule, contexts=("test",))
            self.complete_predictors(client, run_id, uses, metrics)
            log_report(client, run_id, identity.run_name, identity.role, description, metrics)
            return
        paths = {kind: path for kind, path in (("best", best_checkpoint_path(trainer)),
                                               ("last", last_checkpoint_path(trainer))) if path}
        for kind, path in paths.items():
            client.log_artifact(run_id, path, artifact_path=f"checkpoints/{kind}")
        if "fit" in identity.stages:
            nicety("training-progress picture", log_progress_picture, client, run_id,
                   f"{identity.run_name}: training by epoch")
        logged = try_log_student_model(cfg, str(client.tracking_uri), run_id, paths.get("best") or paths.get("last"))
        uses, metrics, description, self.run = describe_run(cfg, ml, datamodule, logged_model=logged)
        self.complete_predictors(client, run_id, uses, metrics)  # no test: the run is still tagged with its role
        log_report(client, run_id, identity.run_name, identity.role, description, metrics)
        nicety("process tags' removal", drop_process_tags, client, run_id, True)
        if paths:
            self.register(ml, "best" if "best" in paths else "last", uses, metrics)

    def complete_predictors(self, client: Any, run_id: str, uses: list[Any], metrics: dict[str, float]) -> None:
        """The child runs with every figure the run ends with: logged when the test did not log them, logged again
        (updated) when figures for them came after it (the baselines' closed-loop figures)."""
        if self._predictors_logged is not None and self._predictors_logged == predictor_figures(metrics):
            return
        log_predictors(self.identity.tags, client, run_id, [u for u in uses if u.context == "test"], metrics)
        self._predictors_logged = predictor_figures(metrics)

    def register(self, ml: Any, kind: str, uses: list[Any], metrics: dict[str, float]) -> None:
        """Register ``checkpoints/<kind>`` when the row asks (``registry.prefix``)."""
        cfg = self.cfg
        name = registry_name(cfg)
        if not name:
            return
        tags = {**dict(self.identity.tags), **dict((cfg.get("registry") or {}).get("tags") or {})}
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
        if status is not None and hasattr(ml, "ended"):
            ml.ended(status)  # Lightning's finalize("failed"), next, keeps it
