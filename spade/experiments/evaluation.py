"""Testing a trained checkpoint on a data config's test set: what ``python -m spade.evaluate`` runs, and what
``also_test`` runs after a training (:func:`spade.experiments.run.test_elsewhere`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import hydra
import lightning as L
from omegaconf import DictConfig, open_dict

from spade.training.instantiate import instantiate_loggers
from spade.training.loading import load_module

__all__ = ["evaluate"]


def _recording(cfg: DictConfig) -> tuple[Path | None, int]:
    """``mcap=`` (a new path, or None) and ``mcap_instances``, checked before anything runs."""
    from spade.experiments.prediction_recording import check_recording_instances
    from spade.ros.recording import check_recording_path

    mcap = check_recording_path(cfg.get("mcap"))
    return mcap, (check_recording_instances(cfg.get("mcap_instances", 64)) if mcap is not None else 0)


def evaluate(cfg: DictConfig) -> dict[str, Any]:
    """Test ``cfg.ckpt_path`` on ``cfg.data``'s test set; returns the test metrics. With ``cfg.mcap`` set, then
    writes the test set's first ``cfg.mcap_instances`` instances with the model's paths, the ground truth and the
    classical baselines as a ROS 2 MCAP recording (:mod:`spade.experiments.prediction_recording`)."""
    from spade.config.evaluate_checks import validate_evaluate_config

    from spade.utils.console import lightning_logs_once

    lightning_logs_once()  # Lightning's lines printed once, not twice (its own handler and the command's)
    options = validate_evaluate_config(cfg)  # role, and the checkpoint's window geometry against the test data's
    if cfg.get("closed_loop"):
        from spade.experiments.closed_loop_evaluation import closed_loop_settings

        closed_loop_settings(cfg.drive, int(cfg.seed))  # a bad drive setting is refused before the test
        from spade.ros.recording import check_recording_path

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
    from spade.training.callbacks import ModelInfo

    # the run records the tested network's size (model/params) as a training run does; no latency timing here
    trainer = hydra.utils.instantiate(cfg.trainer, logger=loggers or False, callbacks=[ModelInfo(latency_runs=0)])
    for lg in loggers:  # the run stays open after the test, until its record is written (spade.tracking.logger)
        lg.hold_open = True
    try:
        results_from_test = bool(cfg.get("open_loop", True) or not cfg.get("closed_loop"))
        if results_from_test:
            # verbose=False: Lightning's table of every figure, unrounded (over a hundred lines), would bury the
            # summary that spade.evaluate prints (spade.tracking.summary.evaluation_summary)
            results = trainer.test(model=model, datamodule=datamodule, verbose=False)[0]
        else:  # closed loop only (open_loop=false): the instance-by-instance test is not run
            results = {}
        if cfg.get("closed_loop"):
            results.update(_closed_loop(cfg, datamodule, loggers, trainer))
        from spade.tracking.runs import finish_evaluation

        finish_evaluation(cfg, trainer, loggers)  # MLflow: experiment kind and description, test data input
        for lg in loggers:  # the record is complete: the run ends
            lg.hold_open = False
            lg.finalize("success")
    except BaseException as exc:  # Ctrl+C or a signal: KILLED, anything else FAILED (as spade.train's runs)
        from spade.tracking.runs import mark_opened_run_ended

        mark_opened_run_ended(loggers, exc)
        raise
    if mcap is not None and trainer.is_global_zero:
        from spade.experiments.prediction_recording import record_test_set

        record_test_set(model, datamodule, mcap, mcap_instances)
    return {k: float(v) for k, v in results.items()}


def _use_models_encoding(datamodule: Any, ckpt_path: str) -> None:
    """Draw the test set's start and goal markers as the model was trained to see them (its file's
    ``data.marker_encoding``), whatever ``data.encoding`` says: a model is never fed another encoding."""
    import logging

    from spade.models.modelfile import read_info

    encoding = str((read_info(ckpt_path).get("data") or {}).get("marker_encoding", "binary"))
    if getattr(datamodule, "encoding", "binary") != encoding:
        logging.getLogger(__name__).info("testing with the model's marker encoding %r (data.encoding was %r)",
                                         encoding, datamodule.encoding)
        datamodule.encoding = encoding


def _closed_loop(cfg: DictConfig, datamodule: Any, loggers: list[Any], trainer: Any) -> dict[str, float]:
    """Drive the test scenarios (:mod:`spade.experiments.closed_loop_evaluation`); log ``closed_loop/*`` and the worst
    episodes' picture to the run."""
    import json
    import tempfile

    from omegaconf import OmegaConf

    from spade.closedloop.picture import episodes_picture
    from spade.experiments.closed_loop_evaluation import episode_summary, run_closed_loop, scenario_set, worst_episodes
    from spade.tracking.runs import mlflow_logger

    drive = OmegaConf.to_container(cfg.drive, resolve=True)
    scenarios = scenario_set(datamodule, drive.get("scenarios"))
    metrics, episodes = run_closed_loop(cfg.ckpt_path, scenarios, drive, int(cfg.seed))
    for lg in loggers:
        lg.log_metrics(metrics, step=trainer.global_step)
    if drive.get("mcap") and trainer.is_global_zero:
        from spade.closedloop.episode_recording import write_episodes_bag

        written = write_episodes_bag(drive["mcap"], episodes["model"][: int(drive.get("mcap_episodes", 20))],
                                     float(drive["follower"]["dt_s"]))
        print(f"closed loop: the model's episodes written to {written}", flush=True)
    ml = mlflow_logger(loggers)
    if ml is not None and trainer.is_global_zero:
        with tempfile.TemporaryDirectory() as tmp:
            worst = worst_episodes(episodes["model"], int(drive.get("pictures", 6)))
            if worst:
                picture = episodes_picture(worst, Path(tmp) / "worst.png",
                                           f"closed loop: the model's {len(worst)} worst of {len(scenarios)} scenarios")
                ml.experiment.log_artifact(ml.run_id, str(picture), "closed_loop")
            summary = Path(tmp) / "episodes.json"
            summary.write_text(json.dumps(episode_summary(episodes), indent=1))
            ml.experiment.log_artifact(ml.run_id, str(summary), "closed_loop")
    return metrics
