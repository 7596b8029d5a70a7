"""Training steps of BC, DBC and Cond-DBC with the same student, and of the expert itself: time, FLOPs, the rate
against a matmul measured in the same run, where the time goes, and what each speed lever changes.

A step is what Lightning runs per batch minus its bookkeeping: ``StudentModule.losses`` (BCE, plus the diffusion
margin of a frozen expert for DBC / Cond-DBC), backward, AdamW step; for the expert, its denoising loss,
backward, AdamW step and EMA update. The experts are fresh
:class:`~spade.training.expert_module.ExpertModule` s with random weights (their cost does not depend on them),
wired into the student exactly as ``StudentModule.load_margin`` wires a trained one (``StudentModule.use_expert``).

The machine may be shared: every figure that is compared with another is measured in the same rounds,
interleaved (one timed step of each variant per round, a matmul reference in every round), and ratios are the
median of the per-round ratios.
"""

from __future__ import annotations

import contextlib
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import torch

from spade.perf.step_cost import matmul_gflops, step_gflop, top_operators
from spade.deploy.export import example_states
from spade.training.expert_module import ExpertModule
from spade.training.margin import MarginConfig
from spade.training.speed import use_bf16_expert
from spade.training.student_module import StudentModule


def student_with_margin(size: str, expert: str | None = None, preset: str = "tiny", **margin: Any) -> Any:
    """A :class:`StudentModule` of ``size``; with the diffusion margin (``margin``: :class:`MarginConfig` options)
    of a fresh ``cond``/``uncond`` expert of ``preset`` if given."""
    module = StudentModule(size=size)
    if expert is not None:
        if expert not in ("cond", "uncond"):
            raise ValueError(f"expert must be 'cond' or 'uncond', got {expert!r}")
        # the default noise schedule (1000 steps, epsilon); no metrics: the module only lends its denoiser
        expert_module = ExpertModule(conditional=expert == "cond", preset=preset,
                                     metrics={"fid": False, "planner": False})
        module.margin_cfg = MarginConfig(**margin)
        module.use_expert(expert_module, source=f"the {expert} expert")
        del expert_module  # the margin keeps the EMA denoiser, not the module's training weights
    return module.train()


@dataclass(frozen=True)
class Setup:
    """What one step trains: ``approach`` BC, DBC, Cond-DBC (a student of ``student``, with the margin of an
    expert of ``preset``) or Expert (a conditional expert of ``preset`` training itself)."""

    approach: str
    student: str | None
    preset: str | None = None
    margin: tuple[tuple[str, Any], ...] = ()

    @property
    def label(self) -> str:
        extra = "".join(f", {k}={v}" for k, v in self.margin)
        if self.approach == "Expert":
            return f"Expert (cond {self.preset}){extra}"
        return f"{self.approach}{' (batch_terms)' if dict(self.margin).get('batch_terms') else ''}"


@dataclass(frozen=True)
class Lever:
    """One way of running the same step: channels_last (model and batch), bf16 autocast (Lightning's
    ``bf16-mixed``: fp32 weights and optimiser, losses in fp32), the AdamW implementation (``foreach``,
    ``fused``; None: torch's default), the margin's frozen expert in bf16."""

    name: str
    channels_last: bool = False
    bf16: bool = False
    optimizer: str | None = None
    expert_bf16: bool = False


#: The levers the bench knows (``training.levers``), each alone or as named.
LEVERS: dict[str, Lever] = {lever.name: lever for lever in (
    Lever("baseline"),
    Lever("channels_last", channels_last=True),
    Lever("bf16", bf16=True),
    Lever("channels_last+bf16", channels_last=True, bf16=True),
    Lever("foreach", optimizer="foreach"),
    Lever("fused", optimizer="fused"),
    Lever("expert_bf16", expert_bf16=True),
)}


def example_batch(batch_size: int, image_size: int, seed: int = 0) -> dict[str, torch.Tensor]:
    """A batch of states and sparse paths (the step's cost does not depend on their content)."""
    generator = torch.Generator().manual_seed(seed)
    state = example_states(batch_size, (image_size, image_size), seed=seed)
    path = (torch.rand(batch_size, 1, image_size, image_size, generator=generator) > 0.97).float()
    return {"state": state, "path": path}


def applies(setup: Setup, lever: Lever) -> bool:
    """Whether ``lever`` changes anything for ``setup`` (the frozen expert exists only with a margin)."""
    return not lever.expert_bf16 or setup.approach in ("DBC", "Cond-DBC")


def build_step(setup: Setup, lever: Lever, batch: dict[str, torch.Tensor]) -> Callable[[], torch.Tensor]:
    """One optimisation step of ``setup`` run as ``lever`` says, as a callable returning the loss."""
    from lightning.pytorch.plugins.precision import MixedPrecision

    if setup.approach == "Expert":
        module = ExpertModule(conditional=True, preset=setup.preset or "tiny", metrics={"fid": False, "planner": False})
        module.train()
    else:
        expert = {"BC": None, "DBC": "uncond", "Cond-DBC": "cond"}[setup.approach]
        module = student_with_margin(setup.student or "medium", expert, setup.preset or "tiny", **dict(setup.margin))
    if lever.expert_bf16:
        use_bf16_expert(module)
    if lever.channels_last:
        module = module.to(memory_format=torch.channels_last)
        batch = {k: v.contiguous(memory_format=torch.channels_last) if v.dim() == 4 else v for k, v in batch.items()}
    options = {} if lever.optimizer is None else {lever.optimizer: True}
    optimizer = torch.optim.AdamW([p for p in module.parameters() if p.requires_grad], lr=1e-3, **options)
    autocast = MixedPrecision("bf16-mixed", "cpu").forward_context if lever.bf16 else contextlib.nullcontext

    def step() -> torch.Tensor:
        optimizer.zero_grad(set_to_none=True)
        with autocast():
            if setup.approach == "Expert":
                loss = module.denoising_loss(module.net, batch)
            else:
                loss = module.losses(batch)["loss"]
        loss.backward()
        optimizer.step()
        if setup.approach == "Expert":
            module.ema.update_parameters(module.net)
        return loss.detach()

    return step


def _timed(fn: Callable[[], Any]) -> float:
    t0 = time.perf_counter()
    fn()
    return (time.perf_counter() - t0) * 1000.0


def interleaved(steps: dict[str, Callable[[], Any]], rounds: int, warmup: int = 1, matmul_size: int = 1024,
                matmul_seconds: float = 0.5) -> tuple[dict[str, list[float]], list[float]]:
    """Milliseconds of each step in each of ``rounds`` rounds (one call of each per round, in turn, after
    ``warmup`` untimed calls of each), and the matmul reference's GFLOP/s measured at the start of every round."""
    for fn in steps.values():
        for _ in range(max(0, warmup)):
            fn()
    times: dict[str, list[float]] = {name: [] for name in steps}
    matmul: list[float] = []
    for _ in range(rounds):
        matmul.append(matmul_gflops(matmul_size, matmul_seconds))
        for name, fn in steps.items():
            times[name].append(_timed(fn))
    return times, matmul


def _rates(gflop: float, ms: list[float], matmul: list[float]) -> dict[str, float]:
    """Median ms, steps/s, achieved GFLOP/s and its ratio to the matmul rate (median of per-round ratios)."""
    median = statistics.median(ms)
    return {"step_ms": median, "step_min_ms": min(ms), "steps_per_s": 1000.0 / median, "gflop": gflop,
            "gflops": gflop / (median / 1000.0), "matmul_gflops": statistics.median(matmul),
            "ratio_to_matmul": statistics.median(gflop / (t / 1000.0) / m for t, m in zip(ms, matmul))}


def default_setups(student: str, cond_presets: Sequence[str], uncond_preset: str | None,
                   expert_presets: Sequence[str], batched_terms: bool = True) -> list[Setup]:
    """BC, DBC (unconditional expert of ``uncond_preset``), Cond-DBC with each conditional expert preset and,
    with ``batched_terms``, Cond-DBC with ``batch_terms=True`` for the first preset; then each expert's own step."""
    setups = [Setup("BC", student)]
    if uncond_preset:
        setups.append(Setup("DBC", student, uncond_preset))
    setups += [Setup("Cond-DBC", student, preset) for preset in cond_presets]
    if batched_terms and cond_presets:
        setups.append(Setup("Cond-DBC", student, cond_presets[0], (("batch_terms", True),)))
    setups += [Setup("Expert", None, preset) for preset in expert_presets]
    return setups


def training_step_times(student: str, image_size: int, batch_size: int, cond_presets: Sequence[str],
                        uncond_preset: str | None, runs: int = 3, warmup: int = 1, batched_terms: bool = True,
                        expert_presets: Sequence[str] = (), matmul_size: int = 1024,
                        matmul_seconds: float = 0.5) -> list[dict[str, Any]]:
    """One row per setup (:func:`default_setups`): GFLOP per step, ms, steps/s, achieved GFLOP/s and its ratio to
    the matmul reference, and the student steps' ratio to BC; all setups timed in the same rounds."""
    batch = example_batch(batch_size, image_size)
    setups = default_setups(student, cond_presets, uncond_preset, expert_presets, batched_terms)
    steps = {s: build_step(s, LEVERS["baseline"], batch) for s in setups}
    gflop = {s: step_gflop(fn) for s, fn in steps.items()}
    times, matmul = interleaved(steps, runs, warmup, matmul_size, matmul_seconds)
    rows = []
    for s in setups:
        rows.append({"approach": s.label, "student": s.student or "-", "expert_preset": s.preset,
                     "image_size": image_size, "batch_size": batch_size, "runs": runs,
                     **_rates(gflop[s], times[s], matmul)})
    bc = next((r["step_ms"] for r in rows if r["approach"] == "BC"), None)
    for row in rows:
        if bc and row["student"] != "-":
            row["ratio_to_bc"] = row["step_ms"] / bc
    return rows


def lever_table(setups: Sequence[Setup], levers: Sequence[str], image_size: int, batch_size: int, rounds: int,
                warmup: int = 1, matmul_size: int = 1024, matmul_seconds: float = 0.5) -> list[dict[str, Any]]:
    """Each lever alone against the same run's baseline, per setup: ms, steps/s, the FLOP rate of the baseline's
    work and its ratio to the matmul, and the speed-up over the baseline (median of per-round ratios)."""
    unknown = [name for name in levers if name not in LEVERS]
    if unknown:
        raise ValueError(f"training.levers: unknown {unknown}; choose from {list(LEVERS)}")
    batch = example_batch(batch_size, image_size)
    rows = []
    for setup in setups:
        chosen = [LEVERS["baseline"], *(LEVERS[n] for n in levers if n != "baseline" and applies(setup, LEVERS[n]))]
        steps = {lever.name: build_step(setup, lever, batch) for lever in chosen}
        gflop = step_gflop(steps["baseline"])  # the same work in every variant
        losses = {name: float(fn()) for name, fn in steps.items()}
        times, matmul = interleaved(steps, rounds, warmup, matmul_size, matmul_seconds)
        base = times["baseline"]
        for lever in chosen:
            ms = times[lever.name]
            rows.append({"setup": setup.label, "expert_preset": setup.preset, "lever": lever.name,
                         "image_size": image_size, "batch_size": batch_size, "rounds": rounds,
                         "loss_finite": bool(torch.isfinite(torch.tensor(losses[lever.name]))),
                         "speedup": statistics.median(b / t for b, t in zip(base, ms)),
                         **_rates(gflop, ms, matmul)})
    return rows


def step_profiles(setups: Sequence[Setup], levers: Sequence[str], image_size: int, batch_size: int,
                  top: int = 10) -> list[dict[str, Any]]:
    """torch.profiler's top operators (self CPU time) of one step of each setup under each lever (after two
    warm-up steps)."""
    batch = example_batch(batch_size, image_size)
    out = []
    for setup in setups:
        for name in levers:
            if not applies(setup, LEVERS[name]):
                continue
            step = build_step(setup, LEVERS[name], batch)
            step()
            step()
            out.append({"setup": setup.label, "lever": name, "image_size": image_size, "batch_size": batch_size,
                        "operators": top_operators(step, top)})
    return out
