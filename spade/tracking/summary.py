"""The closing lines of ``spade.train``: the test figures next to the baselines, and where to open the run.

:func:`run_summary` prints the run's test metrics, each classical baseline's and the untrained model's, then the
``mlflow ui`` command and the URLs of the run and of its experiment's runs table
(:func:`~spade.tracking.links.ui_lines`); the run is the one ``spade.train`` just recorded (the ``run`` its
:func:`~spade.experiments.run.train` returns), else the newest run of that name in the store.

Every line fits :data:`~spade.utils.console.CONSOLE_WIDTH` (a word longer than a line, a path, stays whole): the
figures are one table, a row per figure with the deciding one first (:data:`spade.metrics.catalog.SUMMARY`) and a
column per predictor, shares in per cent; sentences wrap under their label; a command too long for one line
continues on the next with a shell's ``\\``, so that it still pastes as one.
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
from spade.utils.console import CONSOLE_WIDTH, wrap
from spade.deploy.mlflow_models import MODEL_NAME
from spade.metrics.closed_loop_verdict import closed_loop_verdict
from spade.metrics.verdict import verdict_lines, verdicts
from spade.tracking.predictors import TOP_LEVEL_FILTER
from spade.tracking.tables import TINY_NOTICE

log = logging.getLogger(__name__)


def find_run(cfg: DictConfig) -> RunRef | None:
    """The newest run of ``cfg``'s name in its store (the row's own, never a predictor's), with the MLflow Model
    logged on it when there is one."""
    if OmegaConf.select(cfg, "logger.mlflow", default=None) is None:
        return None
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


LABEL_WIDTH = 17
"""The width of a summary line's label (``  label            : text``)."""


def field(label: str, text: str) -> list[str]:
    """``  label            : text``, wrapped within :data:`CONSOLE_WIDTH` under its text."""
    return wrap(text, f"  {label:{LABEL_WIDTH}s}: ")


def command_lines(label: str, words: list[str]) -> list[str]:
    """A ready-to-paste command after its label: one line, or, past :data:`CONSOLE_WIDTH`, several joined by the
    shell's line continuation (`` \\``), so that the lines still paste as one command (a word is never split). The
    continuation lines are indented by 4, not under the label's text: a checkpoint's path (about 75 characters
    under the SPADE home) then fits on one of them."""
    first = f"  {label:{LABEL_WIDTH}s}: "
    lines, line = [], first + words[0]
    for word in words[1:]:
        if len(line) + len(word) + 3 > CONSOLE_WIDTH:  # the word, its space and the continuation's " \\"
            lines.append(line + " \\")
            line = "    " + word
        else:
            line += " " + word
    return [*lines, line]


def guidance_line(history: list[tuple[int, float, float]] | None) -> str | None:
    """One line saying whether the diffusion margin acted, epoch by epoch (``StudentModule.margin_history``)."""
    verdict = guidance_verdict(history)
    return "\n".join(field("guidance", verdict)) if verdict else None


def _who(metrics: dict[str, Any]) -> str:
    """The tested model, as the verdict names it: an expert's test (the expert as a planner) is the only one that
    measures the spread of its samples."""
    return "the expert" if "test/planner/spread_cm" in metrics else "the student"


def learning_verdict(metrics: dict[str, Any]) -> list[str]:
    """The verdict lines of a student's or expert's test (:mod:`spade.metrics.verdict`): the figure that decides,
    the floor where the test set has alternatives, and the model against every classical baseline; one line with
    the likely cause and what to change when it extracted no path at all. Empty when there is no test."""
    failures = metrics.get("test/failure_rate")
    if failures is None:
        return []
    who = _who(metrics)
    if failures >= 0.999:
        return field("verdict", f"{who} extracted no path on any test instance: it has not learned yet. Train longer "
                     "(trainer.max_epochs) or on more demonstrations (the training set's num_instances)")
    # the floor and the BC ceiling have their own lines (floor_lines), and the planner's APE over the floor its row
    lines = [wrapped for line in verdict_lines(metrics, "test", who, with_floor=False)
             for wrapped in field("verdict", line)]
    if any(v.outcome == "loses to" for v in verdicts(metrics, "test")):
        lines += field("verdict", "it loses to a baseline that learns nothing: give it more demonstrations or epochs "
                       "before trusting it")
    return lines


SUMMARY_KEYS = catalog.SUMMARY  # the figures a closing summary prints per predictor (the floor once, alone)


def _predictor_name(prefix: str, model: str) -> str:
    """A figures table's column: ``student`` (``test``), ``straight`` (``test/baseline/straight``), ``untrained``."""
    if prefix == "test":
        return model
    return prefix.rsplit("/", 1)[-1]


def summary_figures(metrics: dict[str, Any], prefixes: list[str]) -> list[str]:
    """The figures as one table: a row per figure of :data:`SUMMARY_KEYS` that a predictor has (the planner's APE,
    which decides, first, then its tail), a column per predictor (``prefixes``: ``test``, ``test/baseline/<name>``,
    ``untrained``), each cell as the results pages format it (shares in per cent; ``n/a`` when not computed)."""
    columns = [(p, _predictor_name(p, _who(metrics).removeprefix("the "))) for p in prefixes
               if any(f"{p}/{k}" in metrics for k in SUMMARY_KEYS)]
    rows = [k for k in SUMMARY_KEYS if any(f"{p}/{k}" in metrics for p, _ in columns)]
    if not rows:
        return []

    def cell(prefix: str, key: str) -> str:
        value = metrics.get(f"{prefix}/{key}")
        return "" if value is None else catalog.fmt(key, float(value))

    title = "test figures"
    first = max(len(title), *(len(catalog.label(k)) for k in rows))
    widths = [max(len(name), *(len(cell(p, k)) for k in rows)) for p, name in columns]
    lines = ["  " + title.ljust(first) + "".join(f"  {name:>{w}}" for (_, name), w in zip(columns, widths))]
    for key in rows:
        lines.append(("  " + catalog.label(key).ljust(first)
                      + "".join(f"  {cell(p, key):>{w}}" for (p, _), w in zip(columns, widths))).rstrip())
    return lines


def floor_lines(metrics: dict[str, Any], prefix: str = "test") -> list[str]:
    """The test set's floor, when it has alternatives, with the BC ceiling and the decoder's floor."""
    floor = metrics.get(f"{prefix}/floor_cm")
    if floor is None or floor != floor:
        return []
    lines = field("floor", f"{float(floor):.2f} cm (APE of the best single path under the test set's alternative "
                  "demonstrations: no predictor can score much below it)")
    ceiling = {k: metrics.get(f"{prefix}/ceiling/planner/{k}") for k in ("ape_cm", "ape_over_floor",
                                                                         "plausibility_cm", "commit_rate")}
    if ceiling["ape_cm"] is not None and ceiling["ape_cm"] == ceiling["ape_cm"]:
        words = {"ape_cm": "planner APE {:.2f} cm", "ape_over_floor": "{:.2f}x the floor",
                 "plausibility_cm": "plausibility {:.2f} cm", "commit_rate": "commits {:.0%}"}
        figures = ", ".join(words[k].format(float(v)) for k, v in ceiling.items() if v is not None)
        lines += field("BC ceiling", f"{figures} (the plausible set's mean image decoded by the planner: the best a "
                       "BC student can plan)")
    target = metrics.get(f"{prefix}/demo_target/planner/ape_cm")
    if target is not None and target == target:
        lines += field("decoder floor", f"planner APE {float(target):.2f} cm (the demonstration's own training "
                       "target decoded by the planner)")
    return lines


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
    lines = field("best checkpoint", checkpoint)
    if str(cfg.model.get("_target_", "")).endswith("StudentModule"):
        data = cfg.get("data") or {}
        own = data.get("train_generate", "unset") is None
        data_args = (f" data=own data.train_dir={data.get('train_dir')} data.test_dir={data.get('test_dir')}"
                     if own else f"{_data_choice()} scale={cfg.scale.name}")
        # one spade.plan syntax (the README's), with the checkpoint's own path: it works from any folder, where a
        # runs:/ URI needs the store the run is in (MLFLOW_TRACKING_URI)
        lines += command_lines("evaluate it", f"python -m spade.evaluate ckpt_path={checkpoint}{data_args}".split())
        lines += command_lines("export it", f"python -m spade.export ckpt_path={checkpoint}".split())
        lines += command_lines("plan with it", f"python -m spade.plan MAP.yaml start=X,Y,YAW goal=X,Y "
                                               f"model={checkpoint}".split())
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
    if ref is not None and ref.model_uri:  # where the model lives in MLflow; the plan command above needs no store
        lines += field("logged model", f"{ref.model_uri} (MLflow's copy of the model, in the store below)")
    lines += ui_lines(uri, ref.experiment_id if ref else None, ref.run_id if ref else None)
    return "\n".join(lines)


def figure_lines(metrics: dict[str, Any], prefixes: list[str]) -> list[str]:
    """The figures of every predictor, the floor, the verdict and the closed loop: what a run's and an
    evaluation's closing lines share."""
    lines = summary_figures(metrics, prefixes) + floor_lines(metrics)
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
    text = f"{int(n)} scenarios"
    if n < SMALL_TEST_SCENARIOS:
        text += (" (a small test, for speed: it tells only large differences apart; the science test set of about 100 "
                 "scenarios on held-out maps is data=site_L, and the results pages give intervals over scenarios)")
    return "\n".join(field("test set", text))


def evaluation_summary(cfg: DictConfig, metrics: dict[str, Any]) -> str:
    """``spade.evaluate``'s closing lines: the same figures, floor and verdict as :func:`run_summary`'s."""
    lines = [f"evaluation of {cfg.get('ckpt_path')} finished"]
    prefixes = ["test", *sorted({"/".join(k.split("/")[:3]) for k in metrics if k.startswith("test/baseline/")})]
    lines += figure_lines(metrics, prefixes)
    return "\n".join(lines)


CLOSED_LOOP_NAMES = {"": "model", "baseline/shortest/": catalog.BASELINE_LABELS["shortest"],
                     "baseline/heading/": catalog.BASELINE_LABELS["heading"],
                     "followed/": "demonstration followed", "demonstration/": "demonstration replayed"}


CLOSED_LOOP_COLUMNS = ("success_rate", "collision_rate", "timeout_rate", "no_plan_rate", "ape_cm", "plausibility_cm",
                       "commit_rate", "mode_switches", "plan_ms")
"""The closed-loop table's columns (``closed_loop/<figure>``): outcome shares, APE over the whole scenario,
plausibility and commitment (where the test set has alternatives), mode switches per scenario and the time of one
plan (the plans per scenario are in the run's metrics: the table fits 120 columns without them)."""


def _closed_loop_header(key: str) -> str:
    """A closed-loop column's header: the catalog's label; a distance's compact header (``APE cm``: the cells are
    centimetres)."""
    return catalog.header(key) if key.endswith("_cm") else catalog.label(f"closed_loop/{key}", qualified=False)


def closed_loop_lines(metrics: dict[str, Any]) -> list[str]:
    """A row per predictor driven in closed loop (``closed_loop/*``), under the number of scenarios driven (see
    :data:`CLOSED_LOOP_COLUMNS`), then the closed loop's verdict
    (:func:`~spade.metrics.closed_loop_verdict.closed_loop_verdict`)."""
    rows = []
    for prefix, name in CLOSED_LOOP_NAMES.items():
        key = f"closed_loop/{prefix}"
        if f"{key}success_rate" not in metrics:
            continue
        m = {k[len(key):]: float(v) for k, v in metrics.items() if k.startswith(key) and "/" not in k[len(key):]}
        rows.append((name, [catalog.fmt(f"closed_loop/{k}", m[k]) if k in m and m[k] == m[k] else ""
                            for k in CLOSED_LOOP_COLUMNS]))
    if not rows:
        return []
    headers = [_closed_loop_header(k) for k in CLOSED_LOOP_COLUMNS]
    first = max(len(name) for name, _ in rows)
    widths = [max(len(header), *(len(cells[i]) for _, cells in rows)) for i, header in enumerate(headers)]
    lines = [f"  closed loop: {int(metrics.get('closed_loop/episodes', 0))} scenarios driven from start to goal",
             "  " + "".ljust(first) + "".join(f"  {h:>{w}}" for h, w in zip(headers, widths))]
    lines += ["  " + name.ljust(first) + "".join(f"  {c:>{w}}" for c, w in zip(cells, widths)) for name, cells in rows]
    verdict = closed_loop_verdict(metrics, _who(metrics))
    return lines + (field("closed loop", verdict) if verdict else [])
