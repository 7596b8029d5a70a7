"""A run's description in the MLflow UI (markdown) and the descriptions of the models it registers.

:func:`run_description` opens with the run's test figures next to the classical baselines and the untrained model
(:func:`figures_table`: rounded, units in the headers), first so that the UI shows it without "Show more", then
the verdict and, for a run driven in closed loop, the closed loop's (:mod:`spade.metrics.closed_loop_verdict`), then
one paragraph: row, approach, data (the test set's composition: :func:`test_composition`),
prerequisites (linked to the runs that trained them), the measured wall time, the command that regenerates it, and
links to its prediction pictures.
:func:`model_description` and :func:`version_description` describe a registered model and one of its versions.
"""

from __future__ import annotations

import logging
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lightning.pytorch.loggers import MLFlowLogger
from omegaconf import DictConfig, OmegaConf

from spade.data.fingerprint import dataset_fingerprint
from spade.metrics import catalog
from spade.paths import CONF_DIR
from spade.tracking.dataset_inputs import DatasetUse, dataset_profile
from spade.tracking.links import artifact_url, relative_run_link
from spade.utils import provenance
from spade.utils.markdown import markdown_table
from spade.metrics.closed_loop_verdict import closed_loop_verdict
from spade.metrics.verdict import verdict_lines
from spade.tracking.registry import data_fingerprint

log = logging.getLogger(__name__)

FIGURES = catalog.DESCRIPTION  # the test figures a description shows, in this order


def _fmt(key: str, value: float | None) -> str:
    """A figure as a description shows it: a tenth of a centimetre, shares in per cent (the header says %)."""
    return catalog.fmt(key, value, compact=True)


def figure_rows(metrics: dict[str, float]) -> list[tuple[str, dict[str, float]]]:
    """(label, {figure: value}) for the run's test figures, each classical baseline (``test/baseline/<name>/``)
    and the untrained model (``untrained/``), in that order; only those the run logged."""
    def logged(stage: str) -> dict[str, float]:
        return {k: metrics[f"{stage}/{k}"] for k in FIGURES if f"{stage}/{k}" in metrics}

    baselines: dict[str, dict[str, float]] = {}
    for key, value in metrics.items():
        match = re.fullmatch(r"test/baseline/([^/]+)/(.+)", key)
        if match and match.group(2) in FIGURES:
            baselines.setdefault(match.group(1), {})[match.group(2)] = value
    rows = [(THIS_MODEL, logged("test")), *((f"baseline: {name}", figs) for name, figs in sorted(baselines.items())),
            ("untrained", logged("untrained"))]
    return [(label, figs) for label, figs in rows if figs]


THIS_MODEL = "this model"


def figures_meaning(shown: tuple[str, ...]) -> str:
    """The line under the figures table: which way is better and what each compact header means, each meaning
    once (:func:`~spade.metrics.catalog.glossary`)."""
    higher = [catalog.header(k) for k in shown if catalog.lower_is_better(k) is False]
    return (f"Lower is better{', except ' + ', '.join(higher) if higher else ''}. "
            + catalog.glossary(shown))


def shown_path(path: str) -> str:
    """A path as a description prints it: relative to ``$SPADE_HOME``, the checkout or the current directory
    (:func:`spade.utils.provenance.shown_path`), else its file name: never the writing machine's absolute path."""
    shown = provenance.shown_path(path)
    return Path(shown).name if os.path.isabs(shown) else shown


def _shown_override(override: str) -> str:
    """A command line's ``key=value`` as a command that still runs: an absolute path under ``$SPADE_HOME`` written
    ``$SPADE_HOME/...`` (the shell expands it on any machine), under the checkout or the current directory relative
    to it (:func:`spade.utils.provenance.shown_path`), anywhere else as given: never cut to its file name."""
    key, sep, value = override.partition("=")
    if not (sep and os.path.isabs(value)):
        return override
    home = os.environ.get("SPADE_HOME")
    if home:
        root, path = Path(os.path.abspath(Path(home).expanduser())), Path(os.path.abspath(value))
        if path == root or root in path.parents:
            return f"{key}=$SPADE_HOME/{path.relative_to(root).as_posix()}"
    return f"{key}={provenance.shown_path(value)}"


GAP = "\u00a0\u00a0"
"""Two no-break spaces before each figure and header: MLflow's markdown tables have no cell padding and HTML collapses
the table's aligning spaces, which ran neighbouring cells together ("FID Hd19 n", "45.3340"); no-break spaces are
not collapsed, and read as spaces in the raw text."""


def figures_table(metrics: dict[str, float]) -> str:
    """The test figures next to the baselines and the untrained model as a markdown table with aligned columns,
    followed by one line saying what each figure means ('' when the run has no test figures)."""
    rows = figure_rows(metrics)
    if not rows:
        return ""
    shown = tuple(k for k in FIGURES if any(k in figs for _, figs in rows))  # no column of n/a only
    cells = [["test set", *(GAP + catalog.header(k) for k in shown)]]
    for label, figs in rows:
        cells.append([f"**{label}**" if label == THIS_MODEL else label, *(GAP + _fmt(k, figs.get(k)) for k in shown)])
    return "\n".join(markdown_table(cells[0], cells[1:], padded=True)) + "\n\n" + figures_meaning(shown)


@dataclass(frozen=True)
class PrerequisiteUse:
    """A model a run was built on: the ``requires`` entry, its checkpoint, and where it was registered."""

    key: str
    experiment: str
    checkpoint: str
    registered: str | None = None  # "<name> v<version>"
    run_link: str | None = None  # markdown link to the run that trained it


def prerequisite_uses(cfg: DictConfig, client: Any | None) -> list[PrerequisiteUse]:
    """The run's prerequisites as resolved: registry-cache checkpoints are traced back to their runs."""
    out = []
    cache = Path(str(OmegaConf.select(cfg, "paths.registry_cache_dir", default="") or "")).resolve()
    for key, req in (cfg.get("requires") or {}).items():
        ckpt = OmegaConf.select(cfg, str(req.target), default=None)
        if ckpt in (None, "", "???"):
            continue
        registered = link = None
        try:
            parts = Path(str(ckpt)).resolve().relative_to(cache).parts
        except ValueError:
            parts = ()  # an explicit checkpoint path, not from the registry
        if client is not None and len(parts) >= 2 and re.fullmatch(r"v\d+", parts[1]):
            name, version = parts[0], parts[1][1:]
            registered = f"{name} v{version}"
            try:
                mv = client.get_model_version(name, version)
                run = client.get_run(mv.run_id)
                link = f"[{run.info.run_name}]({relative_run_link(run.info.experiment_id, mv.run_id)})"
            except Exception as exc:  # noqa: BLE001 - a description must not fail a finished run
                log.warning("prerequisite %s: no run found for %s (%s)", key, registered, exc)
        out.append(PrerequisiteUse(str(key), str(req.experiment), str(ckpt), registered, link))
    return out


def regenerate_command(cfg: DictConfig) -> str | None:
    """The command that makes this run again: the row's experiment at its scale, else the entry point
    (``task_name``: train, evaluate) with the command line's overrides."""
    run_name = str(cfg.get("run_name") or "")
    scale = OmegaConf.select(cfg, "scale.name", default=None)
    from hydra.core.hydra_config import HydraConfig

    overrides = list(HydraConfig.get().overrides.task) if HydraConfig.initialized() else []
    if run_name and (CONF_DIR / "experiment" / f"{run_name}.yaml").is_file():
        # the row at its scale and seed, with the command line's other overrides (its data, above all: a run on
        # the user's datasets regenerates on them, not on the built-in ones); a sweep's own keys are dropped
        dropped = ("+experiment=", "experiment=", "scale=", "seed=", "rows=", "seeds=", "hydra.")
        seed = cfg.get("seed")
        rest = [_shown_override(o) for o in overrides if not o.startswith(dropped)]
        return " ".join([f"python -m spade.train +experiment={run_name}", *([f"scale={scale}"] if scale else []),
                         *([f"seed={seed}"] if seed is not None else []), *rest])
    if overrides or HydraConfig.initialized():
        return " ".join([f"python -m spade.{cfg.get('task_name') or 'train'}",  # train, evaluate
                         *map(_shown_override, overrides)])
    return None


def what_it_is(tags: dict[str, Any]) -> str:
    """``Cond-DBC student``, ``Cond-expert`` (the role is left out when the approach already names it)."""
    approach, role = str(tags.get("approach") or ""), str(tags.get("role") or "")
    if role and role.lower() not in approach.lower():
        return f"{approach} {role}".strip()
    return approach or role or "model"


def guidance_verdict(history: list[tuple[int, float, float]] | None) -> str | None:
    """Whether the diffusion margin acted, epoch by epoch (``StudentModule.margin_history``, or the run's
    ``margin/active`` per epoch), in words; None for an unguided run."""
    if not history:
        return None
    epochs = "  ".join(f"{epoch}: {active:.0%}" for epoch, active, _ in history)
    last = history[-1][1]
    verdict = "acted to the end" if last > 0 else "stopped acting (the expert rates the student at least as " \
        "well as the demonstration: a BC run from then on)"
    return f"margin active by epoch  {epochs}  -> {verdict}"


def wall_time(seconds: float | None) -> str | None:
    """``5 min 43 s``, ``1 h 02 min``, ``12 s`` (None for an unknown time)."""
    if seconds is None or not math.isfinite(seconds) or seconds < 0:
        return None
    total = int(round(seconds))
    if total < 60:
        return f"{total} s"
    minutes, secs = divmod(total, 60)
    if minutes < 60:
        return f"{minutes} min {secs:02d} s"
    hours, minutes = divmod(minutes, 60)
    return f"{hours} h {minutes:02d} min"


def test_composition(use: DatasetUse, shape: str | None = None) -> str:
    """The test set as the run used it, against the set on disk: ``263 L instances of a 600-instance L+U set (40
    scenarios)`` when the run kept part of it (its row's shape), ``all 600 instances (L+U, 40 scenarios)`` when it
    used it whole; the count alone when the manifest cannot be read."""
    used = use.instances
    try:
        profile = dataset_profile(use.root)
    except (OSError, ValueError):
        profile = {}
    total, shapes, scenarios = profile.get("instances"), profile.get("shapes") or [], profile.get("scenarios")
    kinds = "+".join(shapes)
    extra = f"{scenarios} scenarios" if scenarios else ""
    if used is None:
        return "all instances"
    if total is None:
        return f"{used} instances"
    if used >= int(total):
        inside = ", ".join(p for p in (kinds, extra) if p)
        return f"all {used} instances" + (f" ({inside})" if inside else "")
    kept = f"{used} {shape} instances" if shape and len(shapes) > 1 else f"{used} instances"
    return f"{kept} of a {total}-instance{' ' + kinds if kinds else ''} set" + (f" ({extra} in all)" if extra else "")


def run_description(cfg: DictConfig, metrics: dict[str, float], uses: list[DatasetUse],
                    prerequisites: list[PrerequisiteUse], pictures: list[str] | None = None,
                    run: tuple[str, str] | None = None,
                    margin_history: list[tuple[int, float, float]] | None = None,
                    seconds: float | None = None) -> str:
    """A run's description (markdown): the test figures next to the baselines and the untrained model first (the
    lines the MLflow UI shows before "Show more"), the verdict, then row, approach, data, prerequisites, guidance,
    the measured wall time (``seconds``) and the command that regenerates it, and the pictures."""
    tags = dict(cfg.get("tags") or {})
    row = cfg.get("run_name") or tags.get("row") or "run"
    what = what_it_is(tags)
    details = [f"size {tags['size']}" if tags.get("size") else None,
               f"{_fmt('params', metrics['model/params'])} parameters" if "model/params" in metrics else None]
    details_text = ", ".join(d for d in details if d)
    sentence = f"**{row}**: {what or 'model'}" + (f" ({details_text})" if details_text else "")
    if tags.get("shape"):
        sentence += f", {tags['shape']}-shape paths"
    if tags.get("scale"):
        sentence += f", scale `{tags['scale']}`"
    sentence += f"; experiment `{tags.get('table', 'none')}`."
    parts = [sentence]
    train = [u for u in uses if u.context == "training"]
    val = [u for u in uses if u.context == "validation"]
    test = [u for u in uses if u.context == "test"]

    def n(use: DatasetUse) -> str:
        return f"{use.instances} instances" if use.instances is not None else "all instances"

    if train:
        extra = f", validated on {n(val[0])} of its held-out scenarios" if val else ""
        parts.append(f"Trained on `{train[0].name.split(' (')[0]}` ({n(train[0])}{extra}).")
    if test:
        parts.append(f"Tested on `{test[0].name}`: {test_composition(test[0], tags.get('shape'))}.")
    if prerequisites:
        items = []
        for p in prerequisites:
            item = f"{p.key} from `{p.experiment}`"
            if p.registered:
                item += f" (registered model `{p.registered}`" + (f", run {p.run_link})" if p.run_link else ")")
            else:
                item += f" (checkpoint `{shown_path(p.checkpoint)}`)"
            items.append(item)
        parts.append("Prerequisites: " + "; ".join(items) + ".")
    guidance = guidance_verdict(margin_history)
    if guidance:
        parts.append(f"Guidance: {guidance}.")
    took = wall_time(seconds)
    if took:
        parts.append(f"Wall time: {took} (measured: the run's start to its end, test included).")
    command = regenerate_command(cfg)
    if command:
        parts.append(f"Regenerate: `{command}`.")
    table = figures_table(metrics)
    if table:
        figures, meaning = table.split("\n\n", 1)
        text = figures
    else:
        text, meaning = "No test figures (the run was not tested).", ""
    verdict = verdict_lines(metrics, "test", THIS_MODEL)
    if verdict:
        text += "\n\n**Verdict.** " + " ".join(f"{line[0].upper()}{line[1:]}." for line in verdict)
    driven = closed_loop_verdict(metrics, THIS_MODEL)
    if driven:
        text += f"\n\n**Closed loop.** {driven[0].upper()}{driven[1:]}."
    text += "\n\n" + " ".join(parts)
    if meaning:
        text += "\n\n" + meaning
    if pictures:
        shown = [f"[{p}]({artifact_url('', *run, p)})" if run else f"`{p}`" for p in pictures]
        text += "\n\nPictures (Artifacts tab): " + ", ".join(shown) + "."
    return text


def model_description(cfg: DictConfig, uses: list[DatasetUse]) -> str:
    """A registered model's description: what it is, what trained it, on which data."""
    tags = dict(cfg.get("tags") or {})
    what = what_it_is(tags)
    text = (f"SPADE {what}, size `{tags.get('size', '?')}`, for {tags.get('shape', '?')}-shape paths at scale "
            f"`{tags.get('scale', '?')}`, trained by row `{cfg.get('run_name')}` (experiment "
            f"`{tags.get('table', 'none')}`). The name ends in the fingerprint of its training data "
            f"(`{data_fingerprint(cfg)}`, tag `data_fingerprint`): rows that require this model find it by that "
            f"name. Each version links to the run that trained it.")
    train = next((u for u in uses if u.context == "training"), None)
    if train is not None:
        text += f" Training data: `{train.name.split(' (')[0]}` (dataset digest `{dataset_fingerprint(train.root)}`)."
    command = regenerate_command(cfg)
    if command:
        text += f" Retrain: `{command}`."
    return text


def version_description(cfg: DictConfig, ml: MLFlowLogger, metrics: dict[str, float]) -> str:
    """A registered model version's description: the run that trained it (linked) and its test figures."""
    run = ml.experiment.get_run(ml.run_id)
    figures = ", ".join(f"{k} {_fmt(k, metrics[f'test/{k}'])}" for k in FIGURES if f"test/{k}" in metrics)
    link = f"[{run.info.run_name}]({relative_run_link(run.info.experiment_id, ml.run_id)})"
    return f"From run {link}" + (f"; test: {figures}." if figures else " (not tested).")
