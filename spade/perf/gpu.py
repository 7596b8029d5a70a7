"""GPU readiness: the paper's scale, briefly, on one NVIDIA GPU (``python -m spade.gpu_check``).

Development machines here have no GPU, so what the paper scale costs on one is measured by this one script when a
GPU is at hand. It measures, at the paper's geometry (128 px windows, batch 64, bf16 autocast):

- ``steps``: one optimisation step of the 9.2M conditional expert, of the 1-billion-parameter unconditional expert
  (with its peak memory; the batch halves on out-of-memory until it fits), and of a medium student by BC and by
  Cond-DBC with the paper's conditional expert (the margin's extra cost), each the median of ``timed_steps``
  after warm-up, with the peak memory of the step;
- ``sampling``: the conditional expert's DDIM seconds per sample (``ddim_steps``, a batch at once);
- ``pipeline``: the real thing for a few hundred steps, ``python -m spade.train +experiment=t1_medium_conddbc_L
  scale=paper trainer=gpu`` on a freshly annotated paper-scale dataset of ``train_instances``, its conditional
  expert trained first as the row's prerequisite (``train_steps`` each), with the wall time and the test figures
  read back from the run's MLflow store.

Timings synchronise the device around each step (CUDA runs asynchronously). Random weights and synthetic L/U
batches suffice for ``steps`` and ``sampling`` (their cost does not depend on them); the pipeline trains on real
annotated data. ``device=cpu`` with tiny settings runs the same code on a CPU (the test does).
"""

from __future__ import annotations

import contextlib
import logging
import os
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import torch

from spade.metrics import catalog
from spade.perf.bench_report import write_json  # noqa: F401  (the JSON writer of spade.bench, used by the entry point)
from spade.utils.timing import machine_info, measure
from spade.tracking.predictors import TOP_LEVEL_FILTER
from spade.metrics.synthetic import synthetic_batch
from spade.models.builders import count_parameters
from spade.perf.experts import sampling_seconds
from spade.perf.training import student_with_margin
from spade.tracking.client import mlflow_client
from spade.training.expert_module import ExpertModule

log = logging.getLogger(__name__)

__all__ = ["DeviceUnavailableError", "device_info", "expert_step", "format_gpu_report", "gpu_check", "pipeline_run", "sampling_cost",
           "student_step"]


class DeviceUnavailableError(RuntimeError):
    """The requested device is not there (``device=cuda`` without a CUDA GPU)."""


def _check_device(device: str) -> torch.device:
    try:
        dev = torch.device(device)
    except RuntimeError:
        raise ValueError(f"device must be cuda, cuda:N or cpu, got {device!r}") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise DeviceUnavailableError("device=cuda but torch sees no CUDA GPU (torch.cuda.is_available() is False): run this "
                           "on a machine with an NVIDIA GPU and a CUDA build of torch, or pass device=cpu with the "
                           "tiny settings in conf/gpu_check.yaml to check the script itself")
    if dev.type not in ("cuda", "cpu"):
        raise ValueError(f"device must be cuda, cuda:N or cpu, got {device!r}")
    return dev


def device_info(device: torch.device) -> dict[str, Any]:
    """The GPU's name, memory and compute capability, torch and CUDA versions (and the host's CPU)."""
    info: dict[str, Any] = {"device": str(device), **machine_info()}
    if device.type == "cuda":
        props = torch.cuda.get_device_properties(device)
        info.update(gpu=props.name, gpu_memory_gib=round(props.total_memory / 2**30, 1),
                    capability=f"{props.major}.{props.minor}", cuda_version=torch.version.cuda,
                    bf16_supported=torch.cuda.is_bf16_supported())
    return info


def _sync(device: torch.device) -> Callable[[], None]:
    return (lambda: torch.cuda.synchronize(device)) if device.type == "cuda" else (lambda: None)


def _autocast(device: torch.device, precision: str) -> contextlib.AbstractContextManager:
    if precision not in ("bf16", "fp32"):
        raise ValueError(f"precision must be bf16 or fp32, got {precision!r}")
    if precision == "fp32":
        return contextlib.nullcontext()
    return torch.autocast(device_type=device.type, dtype=torch.bfloat16)


@contextlib.contextmanager
def _peak_memory(device: torch.device, out: dict[str, Any]) -> Iterator[None]:
    """Record the peak allocated memory (GiB) of the block into ``out['peak_memory_gib']`` (CUDA only)."""
    if device.type == "cuda":
        torch.cuda.empty_cache()
        torch.cuda.reset_peak_memory_stats(device)
    try:
        yield
    finally:
        if device.type == "cuda":
            out["peak_memory_gib"] = round(torch.cuda.max_memory_allocated(device) / 2**30, 2)


def _batch(batch_size: int, image_size: int, device: torch.device, seed: int = 0) -> dict[str, torch.Tensor]:
    data = synthetic_batch(batch_size, image_size, seed=seed)
    return {"state": torch.from_numpy(data["state"]).to(device), "path": torch.from_numpy(data["path"]).to(device)}


def step_flops(step: Callable[[], torch.Tensor]) -> int:
    """Floating-point operations of one call of ``step`` (forward, backward, optimiser), counted by torch's
    ``FlopCounterMode`` (matrix multiplications and convolutions, the bulk of a U-Net step)."""
    from torch.utils.flop_counter import FlopCounterMode

    counter = FlopCounterMode(display=False)
    with counter:
        step()
    return int(counter.get_total_flops())


def device_busy_share(step: Callable[[], torch.Tensor], device: torch.device, steps: int = 5) -> float | None:
    """The share of the wall time of ``steps`` steady-state steps in which the GPU ran kernels (``torch.profiler``'s
    device time over the wall time); 1 minus it is the share spent outside the GPU (data, Python, host syncs).
    None on a CPU, where there is no device to wait for."""
    if device.type != "cuda":
        return None
    from torch.profiler import ProfilerActivity, profile

    sync = _sync(device)
    sync()
    with profile(activities=[ProfilerActivity.CPU, ProfilerActivity.CUDA]) as prof:
        start = time.perf_counter()
        for _ in range(steps):
            step()
        sync()
        wall = time.perf_counter() - start
    busy_us = sum(getattr(e, "self_device_time_total", 0.0) for e in prof.key_averages())
    return round(min(1.0, busy_us / 1e6 / wall), 3) if wall > 0 else None


def _timed_steps(step: Callable[[], torch.Tensor], device: torch.device, timed_steps: int, warmup: int,
                 peak_tflops: float | None = None) -> dict[str, Any]:
    """Median / min ms of ``step()`` (one optimisation step returning its loss), synchronised, in the steady state
    (after ``warmup`` steps: cuDNN autotuning, allocator); steps/s, the step's FLOPs, achieved TFLOP/s, the model
    FLOPs utilisation against ``peak_tflops`` (when given) and the GPU's busy share; first and last loss."""
    sync = _sync(device)
    losses: list[float] = []

    def run() -> None:
        losses.append(float(step().detach()))
        sync()

    timing = measure(run, timed_steps, warmup)
    out: dict[str, Any] = {"step_ms": round(timing.median_ms, 2), "step_min_ms": round(timing.min_ms, 2),
                           "runs": timing.runs, "steps_per_s": round(1000 / timing.median_ms, 2),
                           "loss_first": losses[0], "loss_last": losses[-1]}
    flops = step_flops(step)
    out["gflop_per_step"] = float(f"{flops / 1e9:.4g}")
    out["achieved_tflops"] = float(f"{flops / (timing.median_ms / 1000) / 1e12:.4g}")
    if peak_tflops:
        out["mfu"] = float(f"{out['achieved_tflops'] / float(peak_tflops):.4g}")
    out["device_busy_share"] = device_busy_share(step, device)
    return out


def _optimiser_step(optimizer: torch.optim.Optimizer, loss_of: Callable[[], torch.Tensor], device: torch.device,
                    precision: str, after: Callable[[], None] | None = None) -> Callable[[], torch.Tensor]:
    """One optimisation step of ``loss_of()`` under the precision's autocast (then ``after()``), returning the loss."""

    def step() -> torch.Tensor:
        optimizer.zero_grad(set_to_none=True)
        with _autocast(device, precision):
            loss = loss_of()
        loss.backward()
        optimizer.step()
        if after is not None:
            after()
        return loss

    return step


def expert_step(conditional: bool, preset: str, image_size: int, batch_size: int, device: torch.device,
                precision: str = "bf16", timed_steps: int = 10, warmup: int = 2,
                prediction_type: str = "sample", peak_tflops: float | None = None) -> dict[str, Any]:
    """One AdamW step of an expert's denoising loss (``ExpertModule.denoising_loss``) with its EMA update; on
    CUDA out-of-memory the batch halves until it fits (reported as ``batch_size``)."""
    row: dict[str, Any] = {"expert": "cond" if conditional else "uncond", "preset": preset, "image_size": image_size}
    module = ExpertModule(conditional=conditional, preset=preset, prediction_type=prediction_type, ema_decay=0.999)
    module.to(device).train()
    row["params_m"] = round(count_parameters(module.net, trainable_only=False) / 1e6, 2)
    optimizer = torch.optim.AdamW(module.net.parameters(), lr=1e-4)
    while True:
        batch = _batch(batch_size, image_size, device)
        step = _optimiser_step(optimizer, lambda: module.denoising_loss(module.net, batch), device, precision,
                               after=lambda: module.ema.update_parameters(module.net))
        try:
            with _peak_memory(device, row):
                row.update(_timed_steps(step, device, timed_steps, warmup, peak_tflops))
            row["batch_size"] = batch_size
            break
        except torch.cuda.OutOfMemoryError:
            if batch_size == 1:
                row.update(batch_size=0, error="out of memory at batch 1")
                break
            log.warning("expert %s: out of memory at batch %d, halving", preset, batch_size)
            optimizer.zero_grad(set_to_none=True)
            batch_size //= 2
    row["samples_per_s"] = round(row["batch_size"] / (row["step_ms"] / 1000), 1) if row.get("step_ms") else None
    return row


def student_step(size: str, expert_preset: str | None, image_size: int, batch_size: int, device: torch.device,
                 precision: str = "bf16", timed_steps: int = 10, warmup: int = 2, expert: str = "cond",
                 peak_tflops: float | None = None) -> dict[str, Any]:
    """One AdamW step of a student's losses: BC (``expert_preset=None``), Cond-DBC (``expert="cond"``) or DBC
    (``expert="uncond"``) with a frozen expert of that preset (random weights, wired as training wires it:
    :func:`spade.perf.training.student_with_margin`)."""
    module = student_with_margin(size, expert if expert_preset else None, expert_preset or "tiny").to(device)
    optimizer = torch.optim.AdamW([p for p in module.parameters() if p.requires_grad], lr=1e-3)
    batch = _batch(batch_size, image_size, device)
    step = _optimiser_step(optimizer, lambda: module.losses(batch)["loss"], device, precision)
    approach = ("Cond-DBC" if expert == "cond" else "DBC") if expert_preset else "BC"
    row: dict[str, Any] = {"approach": approach, "student": size, "expert_preset": expert_preset,
                           "image_size": image_size, "batch_size": batch_size}
    with _peak_memory(device, row):
        row.update(_timed_steps(step, device, timed_steps, warmup, peak_tflops))
    row["samples_per_s"] = round(batch_size / (row["step_ms"] / 1000), 1)
    return row


def sampling_cost(preset: str, image_size: int, batch_size: int, ddim_steps: int, device: torch.device,
                  precision: str = "bf16") -> dict[str, Any]:
    """Seconds per sample of the conditional expert's DDIM loop, ``batch_size`` states at once."""
    module = ExpertModule(conditional=True, preset=preset, prediction_type="sample").to(device).eval()
    state = _batch(batch_size, image_size, device)["state"]
    with _autocast(device, precision):
        cost = sampling_seconds(module, state, "ddim", ddim_steps)
    per_sample = cost["seconds_per_sample"]
    return {"preset": preset, "image_size": image_size, "batch_size": batch_size, "ddim_steps": ddim_steps,
            "batch_s": round(per_sample * batch_size, 3), "ms_per_sample": round(per_sample * 1000, 2)}


def _run_figures(store: Path) -> list[dict[str, Any]]:
    """The runs of an MLflow SQLite store: name, wall seconds, and the test figures a reader compares."""
    client = mlflow_client(f"sqlite:///{store}")
    keys = [catalog.mlflow_key(n) for n in (*catalog.GPU_CHECK, "seconds_per_sample")]
    rows = []
    for experiment in client.search_experiments():
        for run in client.search_runs([experiment.experiment_id], filter_string=TOP_LEVEL_FILTER):
            info, metrics = run.info, run.data.metrics
            wall = (info.end_time - info.start_time) / 1000 if info.end_time and info.start_time else None
            rows.append({"run": info.run_name, "status": info.status, "wall_s": round(wall, 1) if wall else None,
                         **{k.removeprefix("test/"): round(metrics[k], 4) for k in keys if k in metrics}})
    return sorted(rows, key=lambda r: r["run"] or "")


def pipeline_run(experiment: str, overrides: list[str], train_steps: int, work_dir: Path,
                 timeout_s: float) -> dict[str, Any]:
    """``python -m spade.train +experiment=EXPERIMENT OVERRIDES`` for ``train_steps`` optimisation steps per model
    (prerequisites included), into a fresh store under ``work_dir``; its wall time and each run's test figures."""
    home = work_dir
    home.mkdir(parents=True, exist_ok=True)
    command = [sys.executable, "-m", "spade.train", f"+experiment={experiment}", *overrides,
               f"trainer.max_steps={int(train_steps)}", "trainer.max_epochs=10000"]
    env = {**os.environ, "SPADE_HOME": str(home)}
    env.pop("MLFLOW_TRACKING_URI", None)
    log.info("pipeline: %s", " ".join(command[1:]))
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(command, env=env, capture_output=True, text=True, timeout=timeout_s)
        code, tail = proc.returncode, (proc.stdout + proc.stderr)[-3000:]
    except subprocess.TimeoutExpired as exc:
        code = None
        out = exc.stdout or b""
        tail = (out.decode(errors="replace") if isinstance(out, bytes) else out)[-3000:]
    wall = time.perf_counter() - t0
    store = home / "logs" / "mlflow.db"
    row: dict[str, Any] = {"command": " ".join(["python", *command[1:]]), "exit_code": code,
                           "wall_s": round(wall, 1), "timed_out": code is None,
                           "runs": _run_figures(store) if store.is_file() else []}
    if code != 0:
        row["output_tail"] = tail
    return row


def gpu_check(cfg: dict[str, Any]) -> dict[str, Any]:
    """Run the sections of ``conf/gpu_check.yaml`` (``cfg`` resolved to plain data); returns the results."""
    device = _check_device(str(cfg["device"]))
    precision = str(cfg["precision"])
    size, batch, steps, warmup = int(cfg["image_size"]), int(cfg["batch_size"]), int(cfg["timed_steps"]), 2
    sections = list(cfg["sections"])
    unknown = sorted(set(sections) - {"steps", "sampling", "pipeline"})
    if unknown:
        raise ValueError(f"unknown gpu_check sections {unknown}; choose from steps, sampling, pipeline")
    results: dict[str, Any] = {"device": device_info(device), "precision": precision, "settings": dict(cfg)}
    torch.manual_seed(int(cfg.get("seed", 0)))
    t0 = time.perf_counter()
    if "steps" in sections:
        timing = {"precision": precision, "timed_steps": steps, "warmup": warmup, "peak_tflops": cfg.get("peak_tflops")}
        student_expert = cfg.get("student_uncond_preset") or cfg["uncond_preset"]
        rows = [expert_step(True, cfg["cond_preset"], size, batch, device, **timing),
                expert_step(False, cfg["uncond_preset"], size, int(cfg["uncond_batch_size"]), device, **timing),
                student_step(cfg["student"], None, size, batch, device, **timing),
                student_step(cfg["student"], student_expert, size, batch, device, expert="uncond", **timing),
                student_step(cfg["student"], cfg["cond_preset"], size, batch, device, **timing)]
        bc = rows[2]["step_ms"]
        for row in rows[3:]:
            row["ratio_to_bc"] = float(f"{row['step_ms'] / bc:.3g}")  # 3 significant digits at any ratio
        results["steps"] = rows
    if "sampling" in sections:
        results["sampling"] = sampling_cost(cfg["cond_preset"], size, batch, int(cfg["ddim_steps"]), device, precision)
    if "pipeline" in sections:
        p = cfg["pipeline"]
        if not cfg.get("work_dir"):
            raise ValueError("the pipeline section needs work_dir (conf/gpu_check.yaml sets it under the run folder)")
        work = Path(cfg["work_dir"])
        results["pipeline"] = pipeline_run(p["experiment"], list(p["overrides"]), int(cfg["train_steps"]), work,
                                           float(p["timeout_s"]))
    results["seconds"] = round(time.perf_counter() - t0, 1)
    return results


def format_gpu_report(results: dict[str, Any]) -> str:
    """The results as Markdown: the device, the step table, sampling, and the pipeline's runs."""
    d = results["device"]
    lines = [f"# GPU check on {d.get('gpu') or d['device']} ({d.get('gpu_memory_gib', '-')} GiB, torch "
             f"{d['torch']}, CUDA {d.get('cuda_version', '-')}), precision {results['precision']}, "
             f"{results['seconds']} s", ""]
    if "steps" in results:
        lines += ["| step | preset | params (M) | batch | px | ms / step (min) | steps/s | GFLOP / step | TFLOP/s | "
                  "MFU | GPU busy | peak GiB | loss first -> last |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for r in results["steps"]:
            name = f"{r['expert']} expert" if "expert" in r else f"{r['student']} student, {r['approach']}"
            if "ratio_to_bc" in r:
                name += f" ({r['ratio_to_bc']}x BC)"
            timing = f"{r['step_ms']} ({r['step_min_ms']})" if "step_ms" in r else r.get("error", "-")
            loss = f"{r['loss_first']:.4f} -> {r['loss_last']:.4f}" if "loss_first" in r else "-"
            busy = r.get("device_busy_share")
            lines.append(f"| {name} | {r.get('preset') or r.get('expert_preset') or '-'} | {r.get('params_m', '-')} | "
                         f"{r['batch_size']} | {r['image_size']} | {timing} | {r.get('steps_per_s', '-')} | "
                         f"{r.get('gflop_per_step', '-')} | {r.get('achieved_tflops', '-')} | "
                         f"{r.get('mfu', '-') if r.get('mfu') is not None else '-'} | "
                         f"{'-' if busy is None else f'{busy:.0%}'} | {r.get('peak_memory_gib', '-')} | {loss} |")
        lines.append("")
    if "sampling" in results:
        s = results["sampling"]
        lines += [f"Conditional expert `{s['preset']}` DDIM-{s['ddim_steps']}: {s['ms_per_sample']} ms per sample "
                  f"({s['batch_s']} s per batch of {s['batch_size']} at {s['image_size']} px)", ""]
    if "pipeline" in results:
        p = results["pipeline"]
        state = "timed out" if p["timed_out"] else f"exit {p['exit_code']}"
        lines += [f"Pipeline ({state}, {p['wall_s']} s): `{p['command']}`", "",
                  "| run | status | wall s | " + " | ".join(map(catalog.label, catalog.GPU_CHECK)) + " |",
                  "|---|---|---|" + "---|" * len(catalog.GPU_CHECK)]
        for r in p["runs"]:
            lines.append(f"| {r['run']} | {r['status']} | {r['wall_s']} | "
                         + " | ".join(str(r.get(n, "-")) for n in catalog.GPU_CHECK) + " |")
        if p.get("output_tail"):
            lines += ["", "```", p["output_tail"], "```"]
    return "\n".join(lines)
