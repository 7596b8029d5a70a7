"""The closed-loop section of a test: a checkpoint and the classical planners driven through the test set's
scenarios (``python -m spade.evaluate closed_loop=true``; the ``drive`` config group, conf/drive/default.yaml).

Predictors, each logged as ``closed_loop/<prefix><key>`` (:data:`spade.metrics.closed_loop.CLOSED_LOOP_KEYS`):
the model (no prefix), ``baseline/shortest/`` and ``baseline/heading/`` (:class:`spade.closedloop.planners.
BaselinePlanner`, on the student's windows, replanned by the same rule), ``demonstration/`` (replayed exactly: the
reference, success 1 and APE 0 when the scenarios are rebuilt right) and ``followed/`` (the demonstration given to
the follower as its plan: what the follower itself costs).

:class:`ClosedLoopTest` is the one closed-loop section of a run, ``spade.train``'s (the best checkpoint, after the
test) and ``spade.evaluate``'s (its checkpoint) alike: the figures, the worst episodes' picture and every
episode's outcome (``closed_loop/`` artifacts), the model's episodes as a recording when ``drive.mcap`` is set.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any, Mapping

import lightning as L
import numpy as np

from spade.deploy.follower import FollowerSettings
from spade.closedloop.scenario_loading import Scenario, load_scenarios
from spade.closedloop.simulate import ClosedLoopSettings, Episode, drive, replay
from spade.ros.core import CoreSettings
from spade.utils.errors import UserError
from spade.closedloop.episode_recording import write_episodes_bag
from spade.closedloop.picture import episodes_picture
from spade.closedloop.planners import BASELINE_PLANNERS, BaselinePlanner, DemonstrationPlanner
from spade.data.checks import check_dataset
from spade.data.path_dataset import PathDataset
from spade.deploy.student_planner import Planner
from spade.metrics.closed_loop import ClosedLoopMetrics, episode_figures
from spade.tracking.callback import NO_STAGE
from spade.tracking.runs import mlflow_logger
from spade.training.checkpoint_paths import best_checkpoint_path, last_checkpoint_path

__all__ = ["PREDICTOR_PREFIXES", "ClosedLoopTest", "closed_loop_settings", "run_closed_loop", "scenario_set"]

log = logging.getLogger(__name__)

PREDICTOR_PREFIXES = {"model": "", "shortest": "baseline/shortest/", "heading": "baseline/heading/",
                      "demonstration": "demonstration/", "followed": "followed/"}


class ClosedLoopConfigError(UserError, ValueError):
    """A ``drive`` setting the closed loop cannot use."""


def closed_loop_settings(drive_cfg: Mapping[str, Any], seed: int) -> ClosedLoopSettings:
    """The loop's settings from the ``drive`` config section (conf/drive/default.yaml)."""
    d = dict(drive_cfg)
    try:
        follower = FollowerSettings(**dict(d.get("follower") or {}))
        replan = CoreSettings(replan_distance_m=float(d["replan_distance_m"]),
                              replan_every_m=None if d.get("replan_every_m") is None else float(d["replan_every_m"]),
                              min_replan_interval_s=float(d["min_replan_interval_s"]),
                              subgoal_replan_m=float(d["subgoal_replan_m"]))
        return ClosedLoopSettings(follower=follower, replan=replan, goal_tolerance_m=float(d["goal_tolerance_m"]),
                                  budget_factor=float(d["budget_factor"]), budget_extra_s=float(d["budget_extra_s"]),
                                  noise_xy_m=float(d["noise_xy_m"]), noise_yaw_rad=float(d["noise_yaw_rad"]),
                                  initial_offset_m=float(d["initial_offset_m"]),
                                  initial_offset_rad=float(d["initial_offset_rad"]), seed=int(seed))
    except (TypeError, ValueError, KeyError) as err:
        raise ClosedLoopConfigError(f"drive: {err}. See conf/drive/default.yaml for every setting and its meaning"
                                    ) from None


def _shape_indices(dataset: Any, shape: str | None) -> list[int]:
    return [i for i, s in enumerate(dataset.labels("shape")) if shape in (None, s)]


def scenario_set(datamodule: Any, count: int | None) -> list[Scenario]:
    """The scenarios to drive: with ``count`` None, those of the data module's test set (its shape); else a
    scenario set of ``count`` scenarios made with the test set's own generator config, one state per scenario
    (``instances.spacing_m`` beyond any path), in a folder beside the test set (generated once, then reused).
    The same seed and maps give the test set's scenarios first, then more."""
    datamodule.prepare_data()
    datamodule.setup("test")
    test = datamodule.test_set
    dataset = getattr(test, "dataset", test)
    shape = getattr(datamodule, "test_shape", None)
    if count is None:
        indices = list(getattr(test, "indices", range(len(dataset))))
        return load_scenarios(dataset, indices)
    count = int(count)
    if count < 1:
        raise ClosedLoopConfigError(f"drive.scenarios must be null (the test set's) or >= 1, got {count}")
    if datamodule.test_dir is None or datamodule.test_generate is None or datamodule.generator is None:
        raise ClosedLoopConfigError("drive.scenarios=N needs a data config with a test_dir and its test_generate "
                                    "(conf/data/lshape.yaml); use drive.scenarios=null for the test set's own")
    root = Path(datamodule.test_dir).with_name(f"{Path(datamodule.test_dir).name}_scenarios{count}")
    config = _scenario_config(datamodule.test_generate, count, shape)
    check_dataset(root, config, "drive.scenarios")
    if not (root / "manifest.json").is_file():
        log.info("making a closed-loop scenario set of %d scenarios at %s", count, root)
        datamodule.generator(root, config)
    scenarios = PathDataset(root)
    return load_scenarios(scenarios, _shape_indices(scenarios, shape), limit=count)


def _scenario_config(test_generate: Any, count: int, shape: str | None) -> dict[str, Any]:
    from omegaconf import OmegaConf

    config = OmegaConf.to_container(OmegaConf.create(test_generate), resolve=True)
    layers = config.get("set") or []
    layers = list(layers) if isinstance(layers, list) else [layers]
    layer: dict[str, Any] = {"num_instances": count, "instances": {"spacing_m": 1.0e6}}
    if shape is not None:
        layer["shape"] = shape
    config["set"] = [*layers, layer]
    return config


def _figures(episodes: list[Episode], commit_tol_cm: float) -> dict[str, float]:
    metric = ClosedLoopMetrics(commit_tol_cm=commit_tol_cm)
    metric.update(episodes)
    return {k: float(v) for k, v in metric.compute().items()}


def predictors(ckpt_path: str | Path | None, scenarios: list[Scenario], baselines: list[str],
               planner_options: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """The planners to drive, by name: the model (when ``ckpt_path``), the baselines on its windows (or on the
    test set's window when there is no model), the followed demonstration."""
    out: dict[str, Any] = {}
    frame = resolution = margin = None
    if ckpt_path is not None:
        model = Planner(ckpt_path, **{"far_goal": "clip", **dict(planner_options or {})})
        out["model"] = model
        frame, resolution, margin = model.frame, model.resolution, model.margin_m
    for kind in baselines:
        if kind not in BASELINE_PLANNERS:
            raise ClosedLoopConfigError(f"drive.baselines: unknown planner {kind!r}; choose from "
                                        f"{list(BASELINE_PLANNERS)}")
        if frame is None:
            raise ClosedLoopConfigError("closed-loop baselines need the model's window: give a ckpt_path")
        out[kind] = BaselinePlanner(kind, frame, resolution, margin_m=margin, far_goal="clip")
    out["followed"] = DemonstrationPlanner(scenarios)
    return out


def run_closed_loop(ckpt_path: str | Path | None, scenarios: list[Scenario], drive_cfg: Mapping[str, Any],
                    seed: int) -> tuple[dict[str, float], dict[str, list[Episode]]]:
    """Drive ``scenarios`` with the model and the baselines; returns the ``closed_loop/*`` metrics and each
    predictor's episodes."""
    if not scenarios:
        raise ClosedLoopConfigError("no scenarios to drive: the test set holds none of the test shape")
    settings = closed_loop_settings(drive_cfg, seed)
    commit_tol = float(drive_cfg.get("commit_tol_cm", 5.0))
    metrics: dict[str, float] = {}
    episodes: dict[str, list[Episode]] = {}
    t0 = time.perf_counter()
    episodes["demonstration"] = replay(scenarios, settings)
    for name, planner in predictors(ckpt_path, scenarios, list(drive_cfg.get("baselines") or []),
                                    drive_cfg.get("planner")).items():
        started = time.perf_counter()
        episodes[name] = drive(planner, scenarios, settings)
        log.info("closed loop: %s drove %d scenarios in %.1f s", name, len(scenarios), time.perf_counter() - started)
    for name, eps in episodes.items():
        for key, value in _figures(eps, commit_tol).items():
            metrics[f"closed_loop/{PREDICTOR_PREFIXES[name]}{key}"] = value
    metrics["closed_loop/seconds"] = time.perf_counter() - t0
    return metrics, episodes


def worst_episodes(episodes: list[Episode], count: int) -> list[Episode]:
    """The ``count`` worst episodes: failures first, then by APE."""
    scored = [(0 if e.success else 1, episode_figures(e)["ape_cm"], i) for i, e in enumerate(episodes)]
    return [episodes[i] for _, _, i in sorted(scored, reverse=True)[:count]]


def episode_summary(episodes: Mapping[str, list[Episode]]) -> dict[str, Any]:
    """Per predictor, the outcome of every scenario (for the run's JSON artifact)."""
    return {name: [{"scenario": e.scenario.scenario_id, "outcome": e.outcome, "steps": e.steps,
                    "replans": len(e.plans), "end": [float(v) for v in np.asarray(e.path)[-1]]} for e in eps]
            for name, eps in episodes.items()}


class ClosedLoopTest(L.Callback):
    """The closed-loop section of a run (``closed_loop: true``): at the test's end (or, in a run with no stage, at
    its setup) ``ckpt_path`` (else the run's best checkpoint, else its last) and the baselines drive the test set's
    scenarios (:func:`run_closed_loop`); logged as ``closed_loop/*`` at the test's step with the worst episodes'
    picture and ``episodes.json`` (artifacts ``closed_loop/``), before the run's record is completed and the run
    closed; the model's episodes written to ``drive.mcap`` when set. The figures are :attr:`metrics` afterwards."""

    def __init__(self, drive: Mapping[str, Any], seed: int, ckpt_path: str | None = None,
                 datamodule: Any = None) -> None:
        self.drive_cfg = dict(drive)
        self.seed = int(seed)
        self.ckpt_path = ckpt_path
        self.datamodule = datamodule
        self.metrics: dict[str, float] = {}

    def on_test_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self.run(trainer)

    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        if stage == NO_STAGE:
            self.run(trainer)

    def run(self, trainer: L.Trainer) -> None:
        """Drive, log the figures and the artifacts (see the class)."""
        ckpt_path = self.ckpt_path or best_checkpoint_path(trainer) or last_checkpoint_path(trainer)
        if not ckpt_path:
            log.warning("closed loop: no checkpoint to drive")
            return
        drive_cfg = self.drive_cfg
        scenarios = scenario_set(self.datamodule or trainer.datamodule, drive_cfg.get("scenarios"))
        self.metrics, episodes = run_closed_loop(ckpt_path, scenarios, drive_cfg, self.seed)
        for logger in trainer.loggers:
            logger.log_metrics(self.metrics, step=trainer.global_step)
        if not trainer.is_global_zero:
            return
        if drive_cfg.get("mcap"):
            written = write_episodes_bag(drive_cfg["mcap"], episodes["model"][: int(drive_cfg.get("mcap_episodes", 20))],
                                         float(drive_cfg["follower"]["dt_s"]))
            print(f"closed loop: the model's episodes written to {written}", flush=True)
        log_episodes(trainer.loggers, episodes, len(scenarios), int(drive_cfg.get("pictures", 6)))


def log_episodes(loggers: list[Any], episodes: Mapping[str, list[Episode]], scenarios: int, pictures: int) -> None:
    """The worst episodes' picture and every episode's outcome as the MLflow run's ``closed_loop/`` artifacts."""
    import json
    import tempfile

    ml = mlflow_logger(loggers)
    if ml is None:
        return
    with tempfile.TemporaryDirectory() as tmp:
        worst = worst_episodes(episodes["model"], pictures)
        if worst:
            picture = episodes_picture(worst, Path(tmp) / "worst.png",
                                       f"closed loop: the model's {len(worst)} worst of {scenarios} scenarios")
            ml.experiment.log_artifact(ml.run_id, str(picture), "closed_loop")
        summary = Path(tmp) / "episodes.json"
        summary.write_text(json.dumps(episode_summary(episodes), indent=1))
        ml.experiment.log_artifact(ml.run_id, str(summary), "closed_loop")
