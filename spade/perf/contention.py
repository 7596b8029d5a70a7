"""Training throughput under contention: one and two concurrent training processes on the same cores.

A researcher runs a sweep next to an evaluation, a laptop runs a browser: each training process that keeps as
many intra-op threads as there are cores, spinning while they wait for work (OpenMP's active wait), takes cores
from the others. :func:`contention` starts ``processes`` workers at once (``python -m spade.perf.contention``,
each its own interpreter, as separate runs are) under one thread setting, each timing medium-student BC steps
for a fixed wall time, and returns their steps per second; :func:`contention_table` does it solo and with two
processes for each setting and reports each one's speed against the solo speed of the default setting.

A setting is ``{"threads": N or "auto", "wait_policy": "PASSIVE" | "ACTIVE" | None}``; ``auto`` is
:func:`spade.utils.threads.training_threads` (the cores this process may use minus those others keep busy).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from typing import Any
from spade.utils.threads import configure_threads

__all__ = ["contention", "contention_table", "step_loop"]


def step_loop(size: str, image_size: int, batch_size: int, seconds: float, warmup: int = 2) -> dict[str, Any]:
    """BC training steps (forward, BCE, backward, AdamW) of a ``size`` student for ``seconds`` after ``warmup``
    steps; returns steps per second and the thread count torch used."""
    import torch

    from spade.training.student_module import StudentModule

    torch.manual_seed(0)
    module = StudentModule(size=size).train()
    opt = torch.optim.AdamW(module.parameters(), lr=1e-3)
    state = torch.rand(batch_size, 3, image_size, image_size)
    path = (torch.rand(batch_size, 1, image_size, image_size) > 0.97).float()
    batch = {"state": state, "path": path}

    def step() -> None:
        opt.zero_grad(set_to_none=True)
        module.losses(batch)["loss"].backward()
        opt.step()

    for _ in range(warmup):
        step()
    steps, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        step()
        steps += 1
    elapsed = time.perf_counter() - start
    return {"steps": steps, "seconds": elapsed, "steps_per_s": steps / elapsed, "threads": torch.get_num_threads()}


def _worker_env(setting: dict[str, Any]) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_NUM_THREADS", "OMP_WAIT_POLICY")}
    if setting.get("wait_policy"):
        env["OMP_WAIT_POLICY"] = str(setting["wait_policy"])
    return env


def contention(setting: dict[str, Any], processes: int, size: str = "medium", image_size: int = 64,
               batch_size: int = 32, seconds: float = 20.0, start_gap_s: float = 0.0) -> list[dict[str, Any]]:
    """Start ``processes`` workers together under ``setting`` and return each one's :func:`step_loop` result."""
    command = [sys.executable, "-m", "spade.perf.contention", "--worker", json.dumps(
        {"setting": setting, "size": size, "image_size": image_size, "batch_size": batch_size, "seconds": seconds})]
    procs = []
    for _ in range(processes):
        procs.append(subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                      env=_worker_env(setting)))
        time.sleep(start_gap_s)
    out = []
    for proc in procs:
        stdout, stderr = proc.communicate(timeout=seconds * 10 + 300)
        if proc.returncode != 0:
            raise RuntimeError(f"contention worker failed ({proc.returncode}): {stderr[-2000:]}")
        out.append(json.loads(stdout.strip().splitlines()[-1]))
    return out


def contention_table(settings: list[dict[str, Any]], size: str = "medium", image_size: int = 64, batch_size: int = 32,
                     seconds: float = 20.0) -> list[dict[str, Any]]:
    """Solo and two-process steps per second for each setting; ``vs_default_solo`` is each figure over the first
    setting's solo speed (the reference: what a run got before any thread policy)."""
    rows, reference = [], None
    for setting in settings:
        solo = contention(setting, 1, size, image_size, batch_size, seconds)[0]
        pair = contention(setting, 2, size, image_size, batch_size, seconds)
        reference = reference or solo["steps_per_s"]
        rows.append({
            "setting": _label(setting), "solo_steps_per_s": solo["steps_per_s"], "solo_threads": solo["threads"],
            "pair_steps_per_s": [p["steps_per_s"] for p in pair], "pair_threads": [p["threads"] for p in pair],
            "solo_vs_default": solo["steps_per_s"] / reference,
            "pair_vs_own_solo": min(p["steps_per_s"] for p in pair) / solo["steps_per_s"],
            "pair_vs_default_solo": min(p["steps_per_s"] for p in pair) / reference,
        })
    return rows


def _label(setting: dict[str, Any]) -> str:
    threads = setting.get('threads')
    return f"threads={'torch default' if threads is None else threads}, OMP_WAIT_POLICY={setting.get('wait_policy') or 'unset'}"


def format_contention(rows: list[dict[str, Any]], size: str = "medium") -> str:
    """The measured rows as a Markdown table: steps/s alone and each of two together, and their ratios."""
    lines = [f"Training under contention ({size} student, BC steps; two processes started together)", "",
             "| setting | threads (solo / pair) | solo it/s | two processes it/s (each) | each / own solo | "
             "each / default solo |", "|---|---|---|---|---|---|"]
    for r in rows:
        pair = " / ".join(f"{v:.2f}" for v in r["pair_steps_per_s"])
        threads = f"{r['solo_threads']} / {' / '.join(str(t) for t in r['pair_threads'])}"
        lines.append(f"| {r['setting']} | {threads} | {r['solo_steps_per_s']:.2f} | {pair} | "
                     f"{r['pair_vs_own_solo']:.2f} | {r['pair_vs_default_solo']:.2f} |")
    return "\n".join(lines)


def _worker(spec: dict[str, Any]) -> None:
    configure_threads(spec["setting"].get("threads"))
    result = step_loop(spec["size"], spec["image_size"], spec["batch_size"], spec["seconds"])
    print(json.dumps(result), flush=True)


if __name__ == "__main__":  # a worker of contention(); the measurement itself: python -m spade.bench sections=[contention]
    if len(sys.argv) != 3 or sys.argv[1] != "--worker":
        sys.exit("usage: python -m spade.bench sections=[contention] (this module runs its workers)")
    _worker(json.loads(sys.argv[2]))
