"""The expert as a critic, measured: does the diffusion margin rank the demonstration above paths known to be worse?

The margin teaches only where the frozen expert scores the student's path worse than the demonstration
(:mod:`spade.training.margin`). This module measures that ranking on a test set, with the margin's own formulation
(how the path reaches the expert, the timestep band, how one draw compares the two errors): for every instance,
the demonstration and each corruption of :mod:`spade.metrics.corruptions` (and, given a student, the student's
prediction as the margin sees it) go through the expert with *shared* noise and timestep draws, stratified over
equal-width bands of the margin's timestep range. Reported, per candidate and per band:

- ``critic/win/<candidate>``: the share of instances where the demonstration scores better, i.e. where the margin
  of that candidate, averaged over the instance's draws, is > 0, among the instances where the corruption changes
  the image by at least a pixel's worth (the mirror image or the straight line of a straight path *is* the
  demonstration); ``critic/tie/<candidate>`` is the share of instances left out that way. For the student it is
  the share of active margins, over every instance;
- ``critic/ratio/<candidate>``: the candidate's mean denoising error over the demonstration's;
- for a student, ``critic/student/margin`` (the mean clipped margin, an estimate of L_DM) and the rank correlation
  (Spearman) of the instance's margin with how wrong the student is there: ``critic/student/spearman_ape`` (the
  paper extraction's APE), ``critic/student/spearman_planner_ape`` (the planner's path against the demonstration)
  and ``critic/student/spearman_plausibility`` (the planner's path against the nearest plausible demonstration,
  where the test set has alternatives: wrong in a way no operator drew). A critic that teaches gives the worse
  predictions the larger margins; 0 pushes on instances at random.

The FID lesson (README): validate a measuring instrument against known corruptions before trusting what it
measures. ``python -m spade.critic`` runs this on any expert checkpoint; every expert's training run logs it.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch

from spade.data.augment import widen_path
from spade.metrics.corruptions import CORRUPTION_SET_VERSION, CORRUPTIONS, corrupt
from spade.training.expert_module import expert_input
from spade.training.margin import DiffusionMargin
from spade.data.plausible import plausible_images
from spade.metrics._inputs import per_instance_resolution
from spade.metrics.ape import APE
from spade.metrics.decoding import PathDecoder
from spade.metrics.preference import instance_errors
from spade.training.critic_picture import critic_picture
from spade.training.margin import SCORES

__all__ = ["CriticErrors", "band_edges", "critic_metrics", "critic_report", "example_images", "measure_errors"]

STUDENT = "student"


def page_stem(ckpt_path: str, config: Any, student: bool) -> str:
    """The name (without suffix) of ``spade.critic``'s results page and picture for the expert at ``ckpt_path``
    under margin ``config``, with or without a student: the checks refuse to replace it unasked."""
    from pathlib import Path

    stem = f"critic_{'oracle' if getattr(config, 'oracle', False) else Path(str(ckpt_path)).stem}_" \
        f"{config.agent_input}_{config.score}"
    if config.t_min or config.t_max is not None:  # a timestep band other than the expert's whole range
        stem += f"_t{config.t_min}-{config.t_max if config.t_max is not None else 'T'}"
    return stem + ("_student" if student else "")


def band_edges(t_min: int, t_max: int, bands: int) -> list[tuple[int, int]]:
    """``bands`` contiguous, nearly equal-width timestep bands [lo, hi) covering [t_min, t_max)."""
    if bands < 1:
        raise ValueError(f"bands must be >= 1, got {bands}")
    edges = np.linspace(t_min, t_max, min(bands, t_max - t_min) + 1).round().astype(int)
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:]) if b > a]


@dataclass
class CriticErrors:
    """Denoising errors of one critic measurement: ``demo`` and each of ``candidates`` (N, D) for N instances and
    D shared draws, whose timesteps are ``t`` (N, D) and bands ``band`` (D,) (an index into ``bands``);
    ``ape_cm`` (N,) the student's per-instance APE score when a student was measured; ``planner_ape_cm`` and
    ``plausibility_cm`` (N,) its planner path's APE and distance to the nearest plausible demonstration (NaN where
    the planner failed or the instance has no alternatives)."""

    t: torch.Tensor
    band: torch.Tensor
    bands: list[tuple[int, int]]
    demo: torch.Tensor
    candidates: dict[str, torch.Tensor]
    ape_cm: torch.Tensor | None = None
    planner_ape_cm: torch.Tensor | None = None
    plausibility_cm: torch.Tensor | None = None
    differs: dict[str, torch.Tensor] = field(default_factory=dict)
    meta: dict = field(default_factory=dict)

    @property
    def num_instances(self) -> int:
        return int(self.demo.shape[0])


@torch.no_grad()
def _errors(margin: DiffusionMargin, x0s: list[torch.Tensor], cond: torch.Tensor | None, noise: torch.Tensor,
            t: torch.Tensor) -> list[torch.Tensor]:
    """Per-sample errors of each x0 in ``x0s`` under one shared (noise, t), in one expert forward."""
    n = len(x0s)
    b = x0s[0].shape[0]
    x0 = torch.cat(x0s)
    noise_n, t_n = noise.repeat(n, *([1] * (noise.dim() - 1))), t.repeat(n)
    if isinstance(cond, tuple):  # the oracle's plausible set (B, n, 1, H, W) and mask (B, n)
        cond_n = tuple(c.repeat(n, *([1] * (c.dim() - 1))) for c in cond)
    else:
        cond_n = None if cond is None else cond.repeat(n, 1, 1, 1)
    return list(margin.denoising_error(x0, noise_n, t_n, cond_n).split(b))


@torch.no_grad()
def measure_errors(margin: DiffusionMargin, batches: Iterable[dict], robot_x: float, width_px: int,
                   corruptions: Iterable[str] = CORRUPTIONS, student: torch.nn.Module | None = None,
                   draws_per_band: int = 2, bands: int = 5, seed: int = 0, max_instances: int | None = None,
                   device: torch.device | str = "cpu") -> CriticErrors:
    """Denoising errors of the demonstration and of every candidate on ``batches`` (dicts with ``state``, ``path``,
    ``waypoints`` and ``resolution``, as a test loader gives them): each candidate goes through
    :meth:`DiffusionMargin.agent_path` (what the margin does to the student's map), the demonstration is the path
    widened to ``width_px`` (the training target). ``student`` (a StudentModule or any module mapping a state to
    logits) adds its predictions as candidate ``student`` and their APE. Draws are shared by all candidates of an
    instance, ``draws_per_band`` in each of ``bands`` equal bands of the margin's [t_min, t_max)."""
    names = list(corruptions)
    edges = band_edges(margin.config.t_min, margin.t_max, bands)
    gen = torch.Generator(device="cpu").manual_seed(int(seed))
    decoder = PathDecoder(force_endpoints=True)
    ts, demo, apes, planner_apes, plausible = [], [], [], [], []
    cands: dict[str, list[torch.Tensor]] = {name: [] for name in names + ([STUDENT] if student is not None else [])}
    differs: dict[str, list[torch.Tensor]] = {name: [] for name in cands}
    seen = 0
    for batch in batches:
        if max_instances is not None and seen >= max_instances:
            break
        take = slice(None) if max_instances is None else slice(0, max_instances - seen)
        state = batch["state"][take].to(device).float()
        path = batch["path"][take].to(device).float()
        waypoints, resolution = batch["waypoints"][take], batch["resolution"]
        if isinstance(resolution, torch.Tensor) and resolution.dim() > 0:
            resolution = resolution[take]
        b = state.shape[0]
        target = widen_path(path, width_px)
        images = {name: corrupt(name, target, waypoints, robot_x, width_px, seed=seed + seen) for name in names}
        if student is not None:
            prob = torch.sigmoid(student(state))
            images[STUDENT] = prob
            ape = APE()
            ape.update(prob.cpu(), state.cpu(), waypoints.cpu(), resolution)
            apes.append(torch.cat([s.reshape(-1) for s in ape.scores]).float())
            res = per_instance_resolution(resolution, b)
            alts = batch.get("alternatives")
            alts = alts[take].numpy() if alts is not None else None
            wps = waypoints.numpy()
            for i in range(b):
                decoded = decoder.decode_state(prob[i, 0].cpu().numpy(), state[i].cpu().numpy(), float(res[i]))
                errs = instance_errors(decoded.points if decoded.ok else None, wps[i],
                                       None if alts is None else alts[i], float(res[i]) * 100.0)
                planner_apes.append(errs[0])
                plausible.append(errs[1])
        agent = {name: margin.agent_path(img) for name, img in images.items()}
        demo_seen = margin.agent_path(target)  # the demonstration as the margin would see it, once per batch
        for name, img in agent.items():
            differs[name].append(((img - demo_seen).abs().flatten(1).sum(1) >= 1.0).cpu())
        x_demo, cond = expert_input(state, target, margin.conditional)
        if margin.oracle:  # the oracle teacher knows each test instance's plausible set
            alts = batch.get("alternatives")
            if alts is None:
                raise ValueError("the oracle as a critic (margin=oracle) needs a test set with alternative "
                                 "demonstrations; regenerate it with them (alternatives.count=16)")
            images_p, mask = plausible_images(waypoints, alts[take], *state.shape[-2:], width_px)
            cond = margin._oracle_condition((images_p.to(device), mask.to(device)))
        x_cands = {name: expert_input(state, img, margin.conditional)[0] for name, img in agent.items()}
        t_batch, e_demo, e_cand = [], [], {name: [] for name in agent}
        for lo, hi in edges:
            for _ in range(draws_per_band):
                t = torch.randint(lo, hi, (b,), generator=gen).to(device)
                noise = torch.randn(x_demo.shape, generator=gen).to(device)
                errs = _errors(margin, [x_demo, *x_cands.values()], cond, noise, t)
                t_batch.append(t.cpu())
                e_demo.append(errs[0].cpu())
                for name, err in zip(x_cands, errs[1:]):
                    e_cand[name].append(err.cpu())
        ts.append(torch.stack(t_batch, 1))
        demo.append(torch.stack(e_demo, 1))
        for name in agent:
            cands[name].append(torch.stack(e_cand[name], 1))
        seen += b
    if not seen:
        raise ValueError("the critic got no test instances: check data.test_dir (an empty or missing test set)")
    band = torch.arange(len(edges)).repeat_interleave(draws_per_band)
    return CriticErrors(
        t=torch.cat(ts), band=band, bands=edges, demo=torch.cat(demo),
        candidates={name: torch.cat(v) for name, v in cands.items()},
        ape_cm=torch.cat(apes) if apes else None,
        planner_ape_cm=torch.tensor(planner_apes, dtype=torch.float64) if student is not None else None,
        plausibility_cm=torch.tensor(plausible, dtype=torch.float64) if student is not None else None,
        differs={name: torch.cat(v) for name, v in differs.items()},
        meta={"corruption_set": CORRUPTION_SET_VERSION, "draws_per_band": draws_per_band, "seed": seed},
    )


def _spearman(a: torch.Tensor, b: torch.Tensor) -> float:
    """Spearman's rank correlation of ``a`` and ``b`` over the instances where both are finite (NaN with fewer
    than 3 or no spread)."""
    from scipy.stats import spearmanr

    a, b = a.double(), b.double()
    keep = torch.isfinite(a) & torch.isfinite(b)
    a, b = a[keep], b[keep]
    if len(a) < 3 or float(a.std()) == 0 or float(b.std()) == 0:
        return float("nan")
    return float(spearmanr(a.numpy(), b.numpy()).statistic)


def _spearman_search(errors: CriticErrors, margin: DiffusionMargin, student_err: torch.Tensor, values: torch.Tensor,
                     key: str, masks: list[tuple[str, torch.Tensor]]) -> dict[str, float]:
    """The Spearman of the student's per-instance margin with ``values`` under every score of :data:`SCORES` and
    in every timestep band, from the same draws: which formulation knows where the student is wrong, measured
    without a training run each (``critic/search/spearman_<key>/<score>[/<band>]``)."""
    out = {}
    for score in SCORES:
        scores = margin.score(student_err, errors.demo, score=score)
        for suffix, mask in masks:
            out[f"critic/search/spearman_{key}/{score}{suffix}"] = _spearman(scores[:, mask].mean(1), values)
    return out


def critic_metrics(errors: CriticErrors, margin: DiffusionMargin, per_band: bool = True) -> dict[str, float]:
    """The critic's figures (module docstring) from measured errors, with ``margin``'s score (its ``score``
    option; the errors already went through its ``agent_path``)."""
    out: dict[str, float] = {}
    masks = [("", torch.ones_like(errors.band, dtype=torch.bool))]
    if per_band and len(errors.bands) > 1:
        masks += [(f"/t{lo:04d}-{hi:04d}", errors.band == i) for i, (lo, hi) in enumerate(errors.bands)]
    for name, err in errors.candidates.items():
        scores = margin.score(err, errors.demo)  # (N, D)
        counted = torch.ones(errors.num_instances, dtype=torch.bool)
        if name != STUDENT and name in errors.differs:
            counted = errors.differs[name]
            out[f"critic/tie/{name}"] = float(1.0 - counted.float().mean())
        for suffix, mask in masks:
            per_instance = scores[counted][:, mask].mean(1)
            win = float((per_instance > 0).float().mean()) if len(per_instance) else float("nan")
            out[f"critic/win/{name}{suffix}"] = win
            out[f"critic/ratio/{name}{suffix}"] = float(err[:, mask].mean() / errors.demo[:, mask].mean())
        if name == STUDENT:
            per_instance = scores.mean(1)
            out["critic/student/margin"] = float(per_instance.clamp_min(0).mean())
            if errors.ape_cm is not None:
                out["critic/student/spearman_ape"] = _spearman(per_instance, errors.ape_cm)
                out["critic/student/ape_cm"] = float(errors.ape_cm.mean())
            for key, values in (("planner_ape", errors.planner_ape_cm), ("plausibility", errors.plausibility_cm)):
                if values is not None and bool(torch.isfinite(values).any()):
                    out[f"critic/student/spearman_{key}"] = _spearman(per_instance, values)
                    out[f"critic/student/{key}_cm"] = float(values[torch.isfinite(values)].mean())
                    if per_band:
                        out.update(_spearman_search(errors, margin, err, values, key, masks))
    corruption_wins = [v for k, v in out.items() if k.startswith("critic/win/") and k.count("/") == 2
                       and not k.endswith(f"/{STUDENT}") and v == v]
    if corruption_wins:
        out["critic/win_min"] = float(min(corruption_wins))
    return out


def example_images(batch: dict, robot_x: float, width_px: int, corruptions: Iterable[str] = CORRUPTIONS,
                   student: torch.nn.Module | None = None, seed: int = 0) -> tuple[torch.Tensor, dict]:
    """One instance of ``batch`` (the first whose path turns, so that every corruption shows) with its
    demonstration, each corruption and the student's prediction: (state (3, H, W), name -> (1, H, W))."""
    target = widen_path(batch["path"].float(), width_px)
    names = list(corruptions)
    radius = corrupt("radius", target, batch["waypoints"], robot_x, width_px) if "radius" in names else target
    turns = ((radius - target).abs().flatten(1).sum(1) >= 1.0).nonzero().flatten()
    i = int(turns[0]) if len(turns) else 0
    one = slice(i, i + 1)
    images = {"demonstration": target[one]}
    for name in names:
        images[name] = corrupt(name, target[one], batch["waypoints"][one], robot_x, width_px, seed=seed + i)
    if student is not None:
        with torch.no_grad():
            images[STUDENT] = torch.sigmoid(student(batch["state"][one].float()))
    return batch["state"][i], {k: v[0] for k, v in images.items()}


def critic_report(margin: DiffusionMargin, loader: Iterable[dict], robot_x: float, width_px: int,
                  student: torch.nn.Module | None = None, draws_per_band: int = 2, bands: int = 5, seed: int = 0,
                  max_instances: int | None = None, title: str = "") -> tuple[dict[str, float], np.ndarray]:
    """The critic's figures (:func:`critic_metrics` of :func:`measure_errors`) and their picture
    (:func:`~spade.training.critic_picture.critic_picture`) for ``margin`` on ``loader``'s instances."""
    errors = measure_errors(margin, loader, robot_x, width_px, student=student, draws_per_band=draws_per_band,
                            bands=bands, seed=seed, max_instances=max_instances)
    metrics = critic_metrics(errors, margin)
    metrics["critic/instances"] = float(errors.num_instances)
    state, images = example_images(next(iter(loader)), robot_x, width_px, student=student, seed=seed)
    picture = critic_picture(metrics, errors.bands, list(errors.candidates), state, images, title=title)
    return metrics, picture
