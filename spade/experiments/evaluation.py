"""Testing a trained checkpoint on a data config's test set: what ``python -m spade.evaluate`` runs, and what
``also_test`` runs after a training (:func:`spade.experiments.run.test_elsewhere`). The run's MLflow record is kept
by the callback a training run's is (:class:`spade.tracking.callback.RunRecord`), given the evaluation's identity;
its closed-loop section is a training run's too (:class:`spade.experiments.closed_loop_evaluation.ClosedLoopTest`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import hydra
import lightning as L
from omegaconf import DictConfig, OmegaConf, open_dict

from spade.experiments.lifecycle import run_without_stages
from spade.tracking.callback import RunRecord, evaluation_identity
from spade.training.callbacks import ModelInfo
from spade.training.instantiate import instantiate_loggers
from spade.training.loading import load_module
from spade.config.evaluate_checks import validate_evaluate_config
from spade.experiments.closed_loop_evaluation import closed_loop_settings, ClosedLoopTest
from spade.experiments.prediction_recording import check_recording_instances, record_test_set
from spade.models.modelfile import read_info
from spade.ros.recording import check_recording_path
from spade.utils.console import lightning_logs_once

__all__ = ["evaluate"]


def _recording(cfg: DictConfig) -> tuple[Path | None, int]:
    """``mcap=`` (a new path, or None) and ``mcap_instances``, checked before anything runs."""
    mcap = check_recording_path(cfg.get("mcap"))
    return mcap, (check_recording_instances(cfg.get("mcap_instances", 64)) if mcap is not None else 0)


def evaluate(cfg: DictConfig) -> dict[str, Any]:
    """Test ``cfg.ckpt_path`` on ``cfg.data``'s test set; returns the test metrics. With ``cfg.mcap`` set, then
    writes the test set's first ``cfg.mcap_instances`` instances with the model's paths, the ground truth and the
    classical baselines as a ROS 2 MCAP recording (:mod:`spade.experiments.prediction_recording`)."""
    lightning_logs_once()  # Lightning's lines printed once, not twice (its own handler and the command's)
    options = validate_evaluate_config(cfg)  # role, and the checkpoint's window geometry against the test data's
    if cfg.get("closed_loop"):
        closed_loop_settings(cfg.drive, int(cfg.seed))  # a bad drive setting is refused before the test
        check_recording_path(cfg.drive.get("mcap"), "drive.mcap")  # an existing recording is refused now
    mcap, mcap_instances = _recording(cfg)  # refused now, not after the test
    L.seed_everything(cfg.seed, workers=True)
    model = load_module(cfg.ckpt_path, **options.sampling.settings)  # an expert's sampling, where expert_sampling sets it
    datamodule = hydra.utils.instantiate(cfg.data)
    _use_models_encoding(datamodule, cfg.ckpt_path)
    with open_dict(cfg):  # the run records the markers the test drew (tag encoding), not the config's default
        cfg.data.encoding = datamodule.encoding
        if cfg.get("tags") is not None:
            cfg.tags.encoding = datamodule.encoding
    loggers = instantiate_loggers(cfg.get("logger"))  # SPADE's MLflow logger opens a fresh store under a lock
    tested = bool(cfg.get("open_loop", True) or not cfg.get("closed_loop"))  # open_loop=false: the drive alone
    # the tested network's size (model/params) as a training run records it, with no latency timing; the closed
    # loop before the run's record (the figures it describes)
    callbacks: list[L.Callback] = [ModelInfo(latency_runs=0)]
    drive = None
    if cfg.get("closed_loop"):
        drive = ClosedLoopTest(OmegaConf.to_container(cfg.drive, resolve=True), int(cfg.seed), str(cfg.ckpt_path),
                               datamodule)
        callbacks.append(drive)
    callbacks.append(RunRecord(cfg, evaluation_identity(cfg, tested)))
    trainer = hydra.utils.instantiate(cfg.trainer, logger=loggers or False, callbacks=callbacks)
    if tested:
        # verbose=False: Lightning's table of every figure, unrounded (over a hundred lines), would bury the
        # summary that spade.evaluate prints (spade.tracking.summary.evaluation_summary)
        results = trainer.test(model=model, datamodule=datamodule, verbose=False)[0]
    else:  # closed loop only: the instance-by-instance test is not run
        results = {}
        run_without_stages(trainer, model)
    results.update(drive.metrics if drive is not None else {})
    if mcap is not None and trainer.is_global_zero:
        record_test_set(model, datamodule, mcap, mcap_instances)
    return {k: float(v) for k, v in results.items()}


def _use_models_encoding(datamodule: Any, ckpt_path: str) -> None:
    """Draw the test set's start and goal markers as the model was trained to see them (its file's
    ``data.marker_encoding``), whatever ``data.encoding`` says: a model is never fed another encoding."""
    import logging

    encoding = str((read_info(ckpt_path).get("data") or {}).get("marker_encoding", "binary"))
    if getattr(datamodule, "encoding", "binary") != encoding:
        logging.getLogger(__name__).info("testing with the model's marker encoding %r (data.encoding was %r)",
                                         encoding, datamodule.encoding)
        datamodule.encoding = encoding
