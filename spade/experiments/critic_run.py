"""The expert as a critic, measured, logged and written as a page: what ``python -m spade.critic`` runs.

:func:`critic` scores the demonstration against a fixed, versioned set of corruptions (:mod:`spade.metrics.
corruptions`; the measure itself is :mod:`spade.training.critic`) with the margin formulation of ``margin=``, per
timestep band, and the expert as a planner beside the student; logs the figures (``critic/win/*``,
``critic/ratio/*``) and a picture to MLflow (experiment ``critic``, the run's :class:`~spade.tracking.callback.
RunIdentity`) and writes the results page in ``output_dir``; :func:`format_report` is what the command prints.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

import numpy as np
from omegaconf import DictConfig, OmegaConf

from spade.metrics import catalog
from spade.metrics.corruptions import CORRUPTION_SET_VERSION
from spade.tracking.callback import RunIdentity, run_identity
from spade.training.critic import critic_report, page_stem
from spade.data import DatasetError
from spade.data.path_dataset import PathDataset
from spade.deploy.outputs import save_png
from spade.models.modelfile import load_lightning, read_info
from spade.training.expert_module import ExpertModule
from spade.training.instantiate import instantiate_loggers
from spade.training.logging_utils import log_image
from spade.training.margin import DiffusionMargin, MarginConfig, MarginOptionError
from spade.training.student_module import StudentModule
from spade.training.teacher import planner_figures
from spade.utils.provenance import command_line, commit, machine, shown_path

__all__ = ["critic", "critic_identity", "critic_verdict", "format_report"]

log = logging.getLogger(__name__)


def _test_loader(cfg: DictConfig, encoding: str = "binary"):
    """The test set of ``cfg.data`` (its ``test_shape`` only), without the training set a data module needs; its
    start and goal drawn with ``encoding``, the expert's (:attr:`ExpertModule.marker_encoding`)."""
    from torch.utils.data import DataLoader, Subset

    test_dir = cfg.data.get("test_dir")
    if not test_dir or not (Path(str(test_dir)) / "manifest.json").is_file():
        raise DatasetError(
            f"data.test_dir={test_dir} holds no dataset: pass the test set the expert is judged on "
            "(data.test_dir=DIR), or build it first (any `python -m spade.train +experiment=...` of this scale and "
            "data generates it, or `python -m spade.annotate preset=test out_dir=DIR`)"
        )
    dataset = PathDataset(str(test_dir), encoding=encoding)
    shape = cfg.data.get("test_shape")
    idx = [i for i, s in enumerate(dataset.labels("shape")) if shape in (None, s)]
    if not idx:
        raise DatasetError(f"{test_dir}: no test instances of shape {shape!r}; set data.test_shape=null or another")
    return DataLoader(Subset(dataset, idx), batch_size=int(cfg.critic.batch_size)), dataset


def critic(cfg: DictConfig) -> dict[str, Any]:
    """Measure ``cfg.ckpt_path``'s expert as a critic with ``cfg.model.margin``'s formulation; returns the figures."""
    import torch

    start = time.perf_counter()
    try:
        config = MarginConfig.from_options(OmegaConf.to_container(cfg.model.margin, resolve=True) or {})
    except MarginOptionError as exc:
        raise ValueError(exc.at("model.margin.")) from None
    torch.manual_seed(int(cfg.seed))
    role = read_info(str(cfg.ckpt_path), checkpoint=True, required=False).get("role")
    if role != "expert":
        raise ValueError(f"ckpt_path={cfg.ckpt_path} is a {role or 'non-SPADE'} checkpoint, not an expert's: pass a "
                         "diffusion expert (python -m spade.train +experiment=cond_expert_L, or spade/models/weights/)")
    expert = load_lightning(ExpertModule, str(cfg.ckpt_path))
    config.check_expert(expert.conditional, f"ckpt_path={cfg.ckpt_path}")
    loader, dataset = _test_loader(cfg, expert.marker_encoding)
    expert.check_compatible(in_channels=3, image_size=dataset.image_size, source=f"ckpt_path={cfg.ckpt_path}")
    student = None
    if cfg.get("student_ckpt"):
        student = load_lightning(StudentModule, str(cfg.student_ckpt)).eval()
    margin = DiffusionMargin.from_expert(expert, config)
    c = cfg.critic
    metrics, picture = critic_report(
        margin, loader, robot_x=float(dataset.frame["robot_px"][0]), width_px=int(cfg.data.target_width_px),
        student=student, draws_per_band=int(c.draws_per_band), bands=int(c.bands), seed=int(cfg.seed),
        max_instances=c.max_instances, title=f"{Path(str(cfg.ckpt_path)).name}: score={config.score}, "
        f"agent_input={config.agent_input}, t in [{config.t_min}, {margin.t_max})")
    samples = cfg.critic.get("expert_samples", 0)
    if samples and not config.oracle:  # the oracle as a planner: a test's oracle_sample / oracle_medoid references
        metrics.update(planner_figures(expert, loader, samples=int(samples), student=student,
                                       max_instances=c.max_instances))
    _log(cfg, critic_identity(cfg, config), metrics, picture)
    _write_page(cfg, config, metrics, picture, time.perf_counter() - start)
    return metrics


def critic_verdict(metrics: dict[str, float]) -> str:
    """Two or three sentences from the win rates (``critic/win/<candidate>[/<band>]``): whether the expert ranks the
    demonstration above its corruptions in most timestep bands (a win rate above one half in more than half of the
    bands), the weakest corruption and its worst band, and how often the margin against the student is active."""
    bands = sorted({k.rsplit("/", 1)[1] for k in metrics if k.startswith("critic/win/") and k.count("/") == 3})
    names = [k.split("/")[2] for k in metrics if k.startswith("critic/win/") and k.count("/") == 2]
    corruptions = [n for n in names if n != "student"]
    if not corruptions:
        return "No corruption was scored: the page has no verdict on the expert as a critic."

    def band_wins(name: str) -> list[float]:
        return [metrics[f"critic/win/{name}/{b}"] for b in bands if f"critic/win/{name}/{b}" in metrics]

    def ranked(name: str) -> bool:
        wins = band_wins(name) or [metrics[f"critic/win/{name}"]]
        return sum(w > 0.5 for w in wins) > len(wins) / 2

    held = [n for n in corruptions if ranked(n)]
    lost = [n for n in corruptions if n not in held]
    count = f"{len(bands)} timestep bands" if bands else "the timesteps"
    if not lost:
        first = (f"The expert ranks the demonstration above each of its {len(corruptions)} corruptions in most of "
                 f"{count}: as a critic it tells the demonstration from a damaged path.")
    elif len(held) > len(lost):
        first = (f"The expert ranks the demonstration above {len(held)} of its {len(corruptions)} corruptions in most "
                 f"of {count}, but not above {', '.join(lost)}.")
    else:
        first = (f"The expert does not rank the demonstration above its corruptions: it does so in most of {count} "
                 f"for only {len(held)} of {len(corruptions)}" + (f" ({', '.join(held)})" if held else "") + ".")
    weakest = min(corruptions, key=lambda n: metrics[f"critic/win/{n}"])
    sentences = [first]
    wins = {b: metrics[f"critic/win/{weakest}/{b}"] for b in bands if f"critic/win/{weakest}/{b}" in metrics}
    text = f"Its weakest is {weakest}: a win rate of {metrics[f'critic/win/{weakest}']:.0%} over all timesteps"
    if wins:
        band = min(wins, key=wins.get)
        text += f", {wins[band]:.0%} in band {band.replace('t', 't ', 1)}"
    sentences.append(text + ".")
    if "critic/win/student" in metrics:
        sentences.append(f"Against the student, the demonstration scores better on {metrics['critic/win/student']:.0%} "
                         "of the instances: the share where the margin acts.")
    return " ".join(sentences)


def _write_page(cfg: DictConfig, config, metrics: dict[str, float], picture, seconds: float) -> Path | None:
    """The results page: the verdict (:func:`critic_verdict`), the figures (:func:`format_report`), per band, with command, commit, date, machine and
    wall time, next to its picture, in ``cfg.output_dir``."""
    import datetime

    from PIL import Image

    if not cfg.get("output_dir"):
        return None
    out = Path(str(cfg.output_dir))
    out.mkdir(parents=True, exist_ok=True)
    stem = page_stem(str(cfg.ckpt_path), config, bool(cfg.get("student_ckpt")))
    save_png(Image.fromarray(picture), out / f"{stem}.png")
    bands = sorted({k.rsplit("/", 1)[1] for k in metrics if k.startswith("critic/win/") and k.count("/") == 3})
    names = [k.split("/")[2] for k in metrics if k.startswith("critic/win/") and k.count("/") == 2]
    header = "| candidate | win (all t) | " + " | ".join(b.replace("t", "t ", 1) for b in bands) + " | ties | error ratio |"
    rows = [header, "|" + "---|" * (len(bands) + 4)]
    for name in names:
        tie = metrics.get(f"critic/tie/{name}")
        rows.append(f"| {name} | {metrics[f'critic/win/{name}']:.2f} | "
                    + " | ".join(f"{metrics.get(f'critic/win/{name}/{b}', float('nan')):.2f}" for b in bands)
                    + f" | {'-' if tie is None else f'{tie:.2f}'} | {metrics[f'critic/ratio/{name}']:.2f} |")
    student = [f"- {k}: {v:.4g}" for k, v in metrics.items() if k.startswith("critic/student/")]
    planner = _planner_section(metrics) + _search_section(metrics)
    text = "\n".join([
        f"# The expert as a critic: {Path(str(cfg.ckpt_path)).name}, margin on agent input `{config.agent_input}`, "
        f"score `{config.score}`",
        "",
        "## Verdict",
        "",
        critic_verdict(metrics) + " These win rates say whether the expert can judge a path at all; what decides "
        "a guided student is its planner's APE (the [metrics reference](../reference/metrics.md#which-figure-decides)).",
        "",
        "## Figures",
        "",
        f"Margin formulation: score `{config.score}`, agent input `{config.agent_input}`, timesteps "
        f"[{config.t_min}, {config.t_max if config.t_max is not None else 'T'}); "
        f"test set `{shown_path(str(cfg.data.test_dir))}` "
        f"(shape {cfg.data.get('test_shape')}), {int(metrics['critic/instances'])} instances, "
        f"{cfg.critic.draws_per_band} shared noise/timestep draws in each of {cfg.critic.bands} bands, corruption set "
        f"version {CORRUPTION_SET_VERSION}.",
        "",
        "Win: the share of instances where the demonstration scores better than the candidate (the margin of that "
        "candidate is > 0), over the instances the corruption changes (ties: the share it leaves unchanged). "
        "For `student` it is the share of active margins. Error ratio: the candidate's mean denoising error over "
        "the demonstration's.",
        "",
        *rows,
        "",
        *(["Student:", "", *student, ""] if student else []),  # a blank line: Markdown needs one before a list
        *planner,
        f"![critic]({stem}.png)",
        "",
        "Provenance:",
        "",
        f"- command: `{command_line('spade.critic')}`",
        f"- commit: {commit() or 'unknown (not a git checkout)'}",
        f"- date: {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC",
        f"- machine: {machine()}",
        f"- wall time: {seconds:.0f} s",
        "",
    ])
    page = out / f"{stem}.md"
    page.write_text(text)
    print(f"results page: {page}")
    return page


PLANNER_COLUMNS = ("ape_cm", "over_20cm_rate", "failure_rate", "ape_over_floor", "plausibility_cm", "commit_rate")
"""The planner's figures the critic page shows per predictor (labels and formats: :mod:`spade.metrics.catalog`)."""


def _planner_section(metrics: dict[str, float]) -> list[str]:
    """The page's section on the expert as a planner beside the student (:mod:`spade.training.teacher`)."""
    if "expert/planner/ape_cm" not in metrics:
        return []
    k = int(metrics["expert/samples"])
    rows = [("expert, one sample", "expert/planner/"), (f"expert, mean of {k} samples' maps", "expert/mean_map/planner/"),
            (f"expert, medoid of {k} samples' paths", "expert/medoid/planner/"), ("student", "student/planner/")]
    lines = ["The expert as a planner (each path decoded by the planner), on the same "
             f"{int(metrics['expert/instances'])} instances:", "",
             "| predictor | " + " | ".join(catalog.label(f"planner/{key}", qualified=key == "ape_cm")
                                             for key in PLANNER_COLUMNS) + " |",
             "|---|" + "---:|" * len(PLANNER_COLUMNS)]
    for label, prefix in rows:
        if f"{prefix}ape_cm" in metrics:
            cells = [catalog.fmt(f"planner/{key}", metrics[f"{prefix}{key}"]) if f"{prefix}{key}" in metrics
                     else "n/a" for key in PLANNER_COLUMNS]
            lines.append(f"| {label} | " + " | ".join(cells) + " |")
    lines += ["", f"Spread of two samples' planner paths: {metrics['expert/spread_cm']:.2f} cm, against the "
              f"generator's {metrics['expert/generator_spread_cm']:.2f} cm (ratio {metrics['expert/spread_ratio']:.2f}; "
              "1: as wide as the operator's choices). A perfectly calibrated sampler's single sample is about the "
              "generator's spread from the demonstration. Sampling: "
              f"{metrics['expert/seconds_per_sample'] * 1000:.0f} ms per instance and sample on this machine.", ""]
    return lines


def _search_section(metrics: dict[str, float]) -> list[str]:
    """The Spearman of the student's margin with how wrong it is, under each score and timestep band (the same
    draws: :func:`spade.training.critic._spearman_search`), for each figure of wrongness measured."""
    lines: list[str] = []
    for key, what in (("plausibility", "the planner path's distance to the nearest plausible demonstration"),
                      ("planner_ape", "the planner path's APE")):
        prefix = f"critic/search/spearman_{key}/"
        found = {k[len(prefix):]: v for k, v in metrics.items() if k.startswith(prefix)}
        if not found:
            continue
        scores = sorted({k.split("/")[0] for k in found})
        bands = sorted({k.split("/", 1)[1] for k in found if "/" in k})
        lines += [f"Spearman of the student's per-instance margin with {what}, by score and timestep band (the same "
                  "draws; 0.3 or more: the margin pushes hardest where the student is most wrong):", "",
                  "| score | all t | " + " | ".join(b.replace("t", "t ", 1) for b in bands) + " |",
                  "|---|" + "---:|" * (len(bands) + 1)]
        for score in scores:
            cells = [found.get(score, float("nan")), *[found.get(f"{score}/{b}", float("nan")) for b in bands]]
            lines.append(f"| {score} | " + " | ".join(f"{v:.2f}" for v in cells) + " |")
        lines.append("")
    return lines


def critic_identity(cfg: DictConfig, config: Any) -> RunIdentity:
    """The critic's MLflow run: the experts' checkpoints and the margin's formulation as its parameters."""
    from dataclasses import asdict

    return run_identity(cfg, {"ckpt_path": str(cfg.ckpt_path), "student_ckpt": str(cfg.get("student_ckpt")),
                              **{f"margin/{k}": v for k, v in asdict(config).items()}})


def _log(cfg: DictConfig, identity: RunIdentity, metrics: dict[str, float], picture: np.ndarray) -> None:
    """The run's parameters, figures and picture (``critic/critic.png``; a file under ``paths.output_dir``
    without an MLflow logger)."""
    loggers = instantiate_loggers(cfg.get("logger"))
    for logger in loggers:
        logger.log_hyperparams(dict(identity.params))
        logger.log_metrics(metrics, step=0)
        log_image(logger, picture, "critic/critic.png", Path(str(cfg.paths.output_dir)))
        logger.finalize("success")
    if not loggers:
        log_image(None, picture, "critic/critic.png", Path(str(cfg.paths.output_dir)))


def format_report(metrics: dict[str, float]) -> str:
    """The figures as lines: each candidate's overall win rate, tie share and error ratio; then the student's."""
    names = [k.split("/")[2] for k in metrics if k.startswith("critic/win/") and k.count("/") == 2]
    lines = [f"{'candidate':12s} {'win':>6s} {'ties':>6s} {'ratio':>6s}"]
    for name in names:
        tie = metrics.get(f"critic/tie/{name}")
        lines.append(f"{name:12s} {metrics[f'critic/win/{name}']:6.2f} {'' if tie is None else f'{tie:6.2f}':>6s} "
                     f"{metrics[f'critic/ratio/{name}']:6.2f}")
    for key in ("critic/win_min", "critic/student/margin", "critic/student/spearman_ape",
                "critic/student/spearman_planner_ape", "critic/student/spearman_plausibility", "critic/student/ape_cm",
                "expert/planner/ape_cm", "expert/planner/plausibility_cm", "expert/mean_map/planner/ape_cm",
                "student/planner/ape_cm", "student/planner/plausibility_cm", "expert/spread_ratio"):
        if key in metrics:
            lines.append(f"{key}: {metrics[key]:.4g}")
    return "\n".join(lines)


