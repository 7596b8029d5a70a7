"""The closing lines of ``spade.train``: the test figures next to the baselines, and where to open the run.

:func:`run_summary` prints the run's test metrics, each classical baseline's and the untrained model's, then the
``mlflow ui`` command and the URLs of the run and of its experiment's runs table
(:func:`~spade.tracking.links.ui_lines`); the run is the one ``spade.train`` just recorded (the ``run`` its
:func:`~spade.experiments.run.train` returns), else the newest run of that name in the store.
"""

from __future__ import annotations

import logging
from typing import Any

from omegaconf import DictConfig, OmegaConf

from spade.metrics import catalog
from spade.tracking.client import mlflow_client
from spade.tracking.descriptions import guidance_verdict
from spade.tracking.links import ui_lines
from spade.tracking.runs import RunRef

log = logging.getLogger(__name__)


def find_run(cfg: DictConfig) -> RunRef | None:
    """The newest run of ``cfg``'s name in its store (the row's own, never a predictor's), with the MLflow Model
    logged on it when there is one."""
    if OmegaConf.select(cfg, "logger.mlflow", default=None) is None:
        return None
    from spade.deploy.mlflow_models import MODEL_NAME
    from spade.tracking.predictors import TOP_LEVEL_FILTER

    uri = str(cfg.paths.mlflow_tracking_uri)
    client = mlflow_client(uri)
    experiment = client.get_experiment_by_name(str(OmegaConf.select(cfg, "logger.mlflow.experiment_name")))
    if experiment is None:
        return None
    runs = client.search_runs([experiment.experiment_id],  # the row's own run, never one of its predictors'
                              filter_string=f"attributes.run_name = '{cfg.run_name}' and {TOP_LEVEL_FILTER}",
                              order_by=["attributes.start_time DESC"], max_results=1)
    if not runs:
        return None
    info = runs[0].info
    outputs = getattr(runs[0], "outputs", None)
    logged = bool(outputs is not None and outputs.model_outputs)
    return RunRef(uri, experiment.experiment_id, info.run_id, info.run_name,
                  f"runs:/{info.run_id}/{MODEL_NAME}" if logged else None)


def guidance_line(history: list[tuple[int, float, float]] | None) -> str | None:
    """One line saying whether the diffusion margin acted, epoch by epoch (``StudentModule.margin_history``)."""
    verdict = guidance_verdict(history)
    return f"  guidance         : {verdict}" if verdict else None


def learning_verdict(metrics: dict[str, Any]) -> list[str]:
    """The verdict lines of a student's or expert's test (:mod:`spade.metrics.verdict`): the figure that decides,
    the floor where the test set has alternatives, and the model against every classical baseline; one line with
    the likely cause and what to change when it extracted no path at all. Empty when there is no test."""
    from spade.metrics.verdict import verdict_lines, verdicts

    failures = metrics.get("test/failure_rate")
    if failures is None:
        return []
    # an expert's test (the expert as a planner) is the only one that measures the spread of its samples
    who = "the expert" if "test/planner/spread_cm" in metrics else "the student"
    if failures >= 0.999:
        return [f"  verdict          : {who} extracted no path on any test instance: it has not learned yet. "
                "Train longer (trainer.max_epochs) or on more demonstrations (the training set's num_instances)"]
    lines = [f"  verdict          : {line}" for line in verdict_lines(metrics, "test", who)]
    if any(v.outcome == "loses to" for v in verdicts(metrics, "test")):
        lines.append("  verdict          : it loses to a baseline that learns nothing: give it more demonstrations or "
                     "epochs before trusting it")
    return lines


def summary_figures(metrics: dict[str, Any], prefixes: list[str]) -> list[str]:
    """One line per predictor (``prefixes``: ``test``, ``test/baseline/<name>``, ``untrained``) with its figures."""
    lines = []
    for prefix in prefixes:
        vals = [f"{k}={metrics[f'{prefix}/{k}']:.4g}" for k in SUMMARY_KEYS if f"{prefix}/{k}" in metrics]
        if vals:
            label = prefix.replace("test/baseline/", "baseline ")
            lines.append(f"  {label:17s}: " + "  ".join(vals))
    return lines


SUMMARY_KEYS = catalog.SUMMARY  # the figures a closing summary prints per predictor (the floor once, alone)


def floor_line(metrics: dict[str, Any], prefix: str = "test") -> str | None:
    """The test set's floor, when it has alternatives."""
    floor = metrics.get(f"{prefix}/floor_cm")
    if floor is None or floor != floor:
        return None
    line = (f"  floor            : {float(floor):.4g} cm (APE of the best single path under the test set's alternative "
            "demonstrations: no predictor can score much below it)")
    figures = [(k, metrics.get(f"{prefix}/ceiling/planner/{k}")) for k in ("ape_cm", "ape_over_floor",
                                                                           "plausibility_cm", "commit_rate")]
    if figures[0][1] is not None and figures[0][1] == figures[0][1]:
        line += "\n  BC ceiling       : " + "  ".join(f"planner/{k}={float(v):.4g}" for k, v in figures if v is not None)
        line += " (the plausible set's mean image decoded by the planner: the best a BC student can plan)"
    target = metrics.get(f"{prefix}/demo_target/planner/ape_cm")
    if target is not None and target == target:
        line += (f"\n  decoder floor    : planner/ape_cm={float(target):.4g} (the demonstration's own training target "
                 "decoded by the planner)")
    return line


def _data_choice() -> str:
    """`` data=NAME`` when the run's data config is not spade.evaluate's default (lshape), e.g. a sizing row's
    ``onemap_L`` set by its experiment file: the evaluate command must test on the same data."""
    from hydra.core.hydra_config import HydraConfig

    if not HydraConfig.initialized():
        return ""
    choice = HydraConfig.get().runtime.choices.get("data")
    return f" data={choice}" if choice and choice != "lshape" else ""


def next_commands(cfg: DictConfig, checkpoint: str | None) -> list[str]:
    """The best checkpoint's path and ready-to-paste evaluate / export / plan commands for it (a student's)."""
    if not checkpoint:
        return []
    lines = [f"  best checkpoint  : {checkpoint}"]
    if str(cfg.model.get("_target_", "")).endswith("StudentModule"):
        data = cfg.get("data") or {}
        own = data.get("train_generate", "unset") is None
        data_args = (f" data=own data.train_dir={data.get('train_dir')} data.test_dir={data.get('test_dir')}"
                     if own else f"{_data_choice()} scale={cfg.scale.name}")
        lines += [
            f"  evaluate it      : python -m spade.evaluate ckpt_path={checkpoint}{data_args}",
            f"  export it        : python -m spade.export ckpt_path={checkpoint}",
            f"  plan with it     : python -m spade.plan model_path={checkpoint} map=MAP.yaml start=[X,Y,YAW] "
            "goal=[X,Y]",
        ]
    return lines


def run_summary(cfg: DictConfig, metrics: dict[str, Any],
                margin_history: list[tuple[int, float, float]] | None = None, checkpoint: str | None = None,
                run: RunRef | None = None) -> str:
    """The closing lines: test metrics next to the baselines, the verdict against every baseline, the
    margin's activity by epoch (a guided student's ``margin_history``), the best checkpoint with the commands that
    use it, the MLflow Model logged on the run (a student's: ``runs:/RUN_ID/model``, which ``spade.plan model=``
    takes), the ``mlflow ui`` command and URLs to the run (``run``, the one just recorded; else the newest of
    ``cfg``'s name in the store) and to its experiment's runs table."""
    lines = [f"run {cfg.get('run_name')} finished"]
    if (cfg.get("scale") or {}).get("name") == "tiny":  # tiny figures are never read as results
        from spade.experiments.tables import TINY_NOTICE

        lines.append(f"  {TINY_NOTICE}")
    prefixes = ["test", *sorted({"/".join(k.split("/")[:3]) for k in metrics if k.startswith("test/baseline/")}),
                "untrained"]
    lines += figure_lines(metrics, prefixes)
    guidance = guidance_line(margin_history)
    if guidance:
        lines.append(guidance)
    lines += next_commands(cfg, checkpoint)
    uri = str(cfg.paths.mlflow_tracking_uri)
    try:
        ref = run if run is not None and run.run_name == str(cfg.get("run_name")) else find_run(cfg)
    except Exception as exc:  # noqa: BLE001 - the closing lines must not fail a finished run
        log.warning("could not look the run up in %s: %s", uri, exc)
        ref = None
    if ref is not None and ref.model_uri:
        lines.append(f"  logged model     : {ref.model_uri}  (python -m spade.plan MAP.yaml start=X,Y,YAW goal=X,Y "
                     f"model={ref.model_uri})")
    lines += ui_lines(uri, ref.experiment_id if ref else None, ref.run_id if ref else None)
    return "\n".join(lines)


def figure_lines(metrics: dict[str, Any], prefixes: list[str]) -> list[str]:
    """The figures of every predictor, the floor, the verdict and the closed loop: what a run's and an
    evaluation's closing lines share."""
    lines = summary_figures(metrics, prefixes)
    floor = floor_line(metrics)
    if floor:
        lines.append(floor)
    test_set = test_set_line(metrics)
    if test_set:
        lines.append(test_set)
    return lines + learning_verdict(metrics) + closed_loop_lines(metrics)


SMALL_TEST_SCENARIOS = 30
"""Below this many test scenarios a summary says its test can tell only large differences apart."""


def test_set_line(metrics: dict[str, Any], prefix: str = "test") -> str | None:
    """How many scenarios the test scored and, for a small test set, what it can tell."""
    n = metrics.get(f"{prefix}/scenarios")
    if n is None or n != n:
        return None
    line = f"  test set         : {int(n)} scenarios"
    if n < SMALL_TEST_SCENARIOS:
        line += (" (a small test, for speed: it tells only large differences apart; the science test set of about 100 "
                 "scenarios on held-out maps is data=site_L, and the results pages give intervals over scenarios)")
    return line


def evaluation_summary(cfg: DictConfig, metrics: dict[str, Any]) -> str:
    """``spade.evaluate``'s closing lines: the same figures, floor and verdict as :func:`run_summary`'s."""
    lines = [f"evaluation of {cfg.get('ckpt_path')} finished"]
    prefixes = ["test", *sorted({"/".join(k.split("/")[:3]) for k in metrics if k.startswith("test/baseline/")})]
    lines += figure_lines(metrics, prefixes)
    return "\n".join(lines)


CLOSED_LOOP_NAMES = {"": "model", "baseline/shortest/": catalog.BASELINE_LABELS["shortest"],
                     "baseline/heading/": catalog.BASELINE_LABELS["heading"],
                     "followed/": "demonstration followed", "demonstration/": "demonstration replayed"}


def closed_loop_lines(metrics: dict[str, Any]) -> list[str]:
    """One line per predictor driven in closed loop (``closed_loop/*``): outcome rates, APE over the whole
    scenario, plausibility, mode switches and replanning change."""
    lines = []
    for prefix, name in CLOSED_LOOP_NAMES.items():
        key = f"closed_loop/{prefix}"
        if f"{key}success_rate" not in metrics:
            continue
        m = {k[len(key):]: float(v) for k, v in metrics.items() if k.startswith(key) and "/" not in k[len(key):]}
        text = (f"success {m['success_rate']:.0%}, collision {m['collision_rate']:.0%}, timeout {m['timeout_rate']:.0%}"
                f", no plan {m['no_plan_rate']:.0%}; APE {m['ape_cm']:.2f} cm")
        if m.get("plausibility_cm") == m.get("plausibility_cm"):
            text += f", plausibility {m['plausibility_cm']:.2f} cm, commits {m['commit_rate']:.0%}"
        text += (f"; {m['mode_switches']:.2f} mode switches and {m['replans']:.1f} plans per scenario, "
                 f"{m['plan_ms']:.1f} ms a plan")
        lines.append(f"  closed loop {name:<24}: {text}")
    if lines:
        lines.insert(0, f"  closed loop: {int(metrics.get('closed_loop/episodes', 0))} scenarios driven from start to goal")
    return lines
