"""The reference step times of a table's cost model, measured on this machine and written with their provenance.

``python -m spade.perf.cost_model`` times one optimisation step (loss, backward, AdamW; no Lightning bookkeeping)
of every kind of run a table holds, at batch 32 and 64 px windows with the cpu scale's ``cpu_lite`` experts: the
students by BC, DBC and Cond-DBC at each size, and the conditional and unconditional experts' denoising step. It
writes them to ``spade/experiments/cost_model.json`` with the command, commit, date, machine and wall time;
:mod:`spade.experiments.multirun` reads that file for a table's time estimate (and scales it by a step timed on
the machine at hand). No step time is typed into the code.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import torch

from spade.utils.timing import machine_info, step_time
from spade.deploy.export import example_states
from spade.perf.training import student_with_margin
from spade.training.expert_module import ExpertModule

__all__ = ["KINDS", "measure_cost_model", "write_cost_model"]

#: The kinds of run a table holds (spade.experiments.multirun's ``_kind`` of a composed row).
KINDS: tuple[str, ...] = tuple(f"{approach}/{size}" for approach in ("bc", "dbc", "conddbc")
                               for size in ("small", "medium", "large")) + ("expert/cond", "expert/uncond")
BATCH, IMAGE_SIZE, EXPERT_PRESET = 32, 64, "cpu_lite"
OUT = Path(__file__).resolve().parents[1] / "experiments" / "cost_model.json"


class _ExpertStep(torch.nn.Module):
    """An expert's training step in the shape :func:`spade.utils.timing.step_time` times (``losses()["loss"]``)."""

    def __init__(self, conditional: bool) -> None:
        super().__init__()
        self.module = ExpertModule(conditional=conditional, preset=EXPERT_PRESET, prediction_type="sample",
                                   metrics={"fid": False, "planner": False})

    def losses(self, batch: dict) -> dict[str, torch.Tensor]:
        return {"loss": self.module.denoising_loss(self.module.net, batch)}


def _module(kind: str) -> Any:
    approach, size = kind.split("/")
    if approach == "expert":
        return _ExpertStep(size == "cond")
    expert = {"bc": None, "dbc": "uncond", "conddbc": "cond"}[approach]
    return student_with_margin(size, expert, EXPERT_PRESET)


def measure_cost_model(runs: int = 5, warmup: int = 2, kinds: tuple[str, ...] = KINDS) -> dict[str, float]:
    """Median seconds of one step of each kind (:data:`KINDS`) at batch 32, 64 px."""
    torch.manual_seed(0)
    batch = {"state": example_states(BATCH, (IMAGE_SIZE, IMAGE_SIZE), seed=0),
             "path": (torch.rand(BATCH, 1, IMAGE_SIZE, IMAGE_SIZE) > 0.97).float()}
    out = {}
    for kind in kinds:
        out[kind] = round(step_time(_module(kind), batch, runs=runs, warmup=warmup)["step_ms"] / 1000, 4)
        print(f"  {kind:<16} {out[kind]:.3f} s/step", flush=True)
    return out


def _commit() -> str | None:
    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                              cwd=Path(__file__).parent, timeout=10).stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        return None


def write_cost_model(step_seconds: dict[str, float], wall_s: float, path: Path = OUT,
                     command: str | None = None) -> Path:
    """Write the measured step times with their provenance (what :mod:`spade.experiments.multirun` reads)."""
    record = {
        "step_seconds": step_seconds,
        "batch_size": BATCH, "image_size": IMAGE_SIZE, "expert_preset": EXPERT_PRESET,
        "command": command or " ".join(["python -m spade.perf.cost_model", *sys.argv[1:]]),
        "commit": _commit(), "date": dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds"),
        "machine": machine_info(), "wall_s": round(wall_s, 1),
    }
    path.write_text(json.dumps(record, indent=2) + "\n")
    return path


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", type=int, default=5, help="timed steps per kind (the median is kept)")
    parser.add_argument("--out", type=Path, default=OUT, help="where to write the record")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    steps = measure_cost_model(args.runs)
    print(f"wrote {write_cost_model(steps, time.perf_counter() - start, args.out)}")


if __name__ == "__main__":
    main()
