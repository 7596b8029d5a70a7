"""Replanning consistency in closed loop: students driven with the replanning prior off and on.

``python -m spade.perf.replanning --ckpt A.ckpt [--ckpt B.ckpt ...] [--weights 0 0.8 0.9] [--keep none 0.5]
[--data site_L] [--scale quickstart] [--scenarios N] --out docs/results/records/replanning/``

Each checkpoint drives the test set's scenarios of ``data`` (the data config, at ``scale``) in closed loop under
each condition (clean, and perturbed as ``conf/closed_loop.yaml``'s) with ``replan_prior`` set to each weight
(:class:`spade.deploy.student_planner.Planner`; 0: off) and ``replan_keep`` to each ``--keep`` value (``none``: off;
a setting with both off is driven once), through the code ``spade.evaluate closed_loop=true`` runs
(:func:`spade.experiments.closed_loop_evaluation.run_closed_loop`, no baselines, no MLflow run): its
``closed_loop/*`` figures, with the followed demonstration beside them. One JSON record per checkpoint, weight and
condition (the figures, the checkpoint, the settings, the command) is written to ``--out``, with
``summary.json``: the mean and sd over the checkpoints. ``priors`` counts the model's plans by what became of their
previous plan (``None``: none given, the first plan, or the prior off; ``used``; ``blocked``; ``outside``).
``paths.data_dir`` is where the test set lives (``SPADE_HOME``'s data folder unless ``--data-dir``).
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
import subprocess
import sys
import time
from pathlib import Path
from typing import Any
from spade.experiments.closed_loop_evaluation import run_closed_loop, scenario_set
from spade.experiments.run_records import _shown as shown
from spade.utils.config import compose_config

__all__ = ["CONDITIONS", "FIGURES", "drive_records", "summarise"]

CONDITIONS: dict[str, dict[str, float]] = {
    "clean": {},
    "perturbed": {"noise_xy_m": 0.03, "noise_yaw_rad": 0.03, "initial_offset_m": 0.2, "initial_offset_rad": 0.35},
}
"""The closed-loop page's conditions (conf/closed_loop.yaml)."""

FIGURES = ("ape_cm", "mode_switches", "commit_rate", "success_rate", "replan_change_cm", "plausibility_cm",
           "smoothness_deg_per_m", "plan_ms")
"""What :func:`summarise` reports (every ``closed_loop/*`` figure is in the records)."""


def _shown(value: str) -> str:
    """A path as a committed record keeps it: relative to the project, or its last parts, never the writing
    machine's folders (:func:`spade.experiments.run_records._shown`, the run records' rule)."""
    return shown(value)


def _git_commit() -> str | None:
    try:
        return subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=True,
                              cwd=Path(__file__).parent).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None


def settings_of(weights: list[float], keeps: list[float | None]) -> list[tuple[float, float | None]]:
    """The (replan_prior, replan_keep) pairs driven: every combination, the keep values on top of each weight."""
    return list(dict.fromkeys((float(w), None if k is None else float(k)) for w in weights for k in keeps))


def drive_records(ckpts: list[str], weights: list[float], conditions: list[str], data: str = "site_L",
                  scale: str = "quickstart", scenarios: int | None = None, data_dir: str | None = None,
                  seed: int = 42, command: str = "", keeps: list[float | None] | None = None) -> list[dict[str, Any]]:
    """Drive every checkpoint under every condition and ``replan_prior`` weight; one record each (module
    docstring). ``scenarios``: the first N of the test set's (None: all)."""
    import hydra
    from omegaconf import OmegaConf

    unknown = sorted(set(conditions) - set(CONDITIONS))
    if unknown:
        raise ValueError(f"condition {unknown[0]!r}: choose from {list(CONDITIONS)}")
    overrides = [f"data={data}", f"scale={scale}", f"ckpt_path={ckpts[0]}"]
    if data_dir:
        overrides.append(f"paths.data_dir={data_dir}")
    cfg = compose_config("evaluate", overrides)
    datamodule = hydra.utils.instantiate(cfg.data)
    chosen = scenario_set(datamodule, None)
    if scenarios is not None:
        chosen = chosen[: int(scenarios)]
    base = OmegaConf.to_container(cfg.drive, resolve=True)
    base["baselines"] = []
    records = []
    for ckpt in ckpts:
        for condition in conditions:
            for weight, keep in settings_of(weights, keeps or [None]):
                drive = {**base, **CONDITIONS[condition],
                         "planner": {"replan_prior": weight, "replan_keep": keep}}  # None: off, not the default
                t0 = time.perf_counter()
                metrics, episodes = run_closed_loop(ckpt, chosen, drive, seed)
                priors: dict[str, int] = {}
                for ep in episodes["model"]:
                    for plan in ep.plans:
                        key = str(getattr(plan, "prior", None))
                        priors[key] = priors.get(key, 0) + 1
                records.append({
                    "checkpoint": _shown(str(ckpt)), "run": Path(ckpt).parent.parent.name, "condition": condition,
                    "replan_prior": weight, "replan_keep": keep, "scenarios": len(chosen), "data": data,
                    "scale": scale,
                    "seed": seed, "settings": {k: drive[k] for k in sorted(drive) if k not in ("pictures", "mcap")},
                    "metrics": {k: (None if not math.isfinite(v) else round(v, 6)) for k, v in sorted(metrics.items())},
                    "priors": dict(sorted(priors.items())), "seconds": round(time.perf_counter() - t0, 1),
                    "commit": _git_commit(), "command": " ".join(_shown(w) for w in command.split(" ")),
                })
                m = records[-1]["metrics"]
                print(f"{records[-1]['run']} {condition} replan_prior={weight:g} replan_keep={keep}: APE "
                      f"{m['closed_loop/ape_cm']:.2f} cm, mode switches {m['closed_loop/mode_switches']:.2f}, commits "
                      f"{m['closed_loop/commit_rate']:.2f}, success {m['closed_loop/success_rate']:.2f} "
                      f"({records[-1]['seconds']:.0f} s)", flush=True)
    return records


def summarise(records: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Mean and sd (over the checkpoints) of :data:`FIGURES` per condition and weight."""
    import numpy as np

    groups: dict[tuple[str, float, float], list[dict[str, Any]]] = {}
    for r in records:
        keep = r.get("replan_keep")
        groups.setdefault((r["condition"], r["replan_prior"], -1.0 if keep is None else keep), []).append(r)
    out = []
    for (condition, weight, keep), rows in sorted(groups.items()):
        row: dict[str, Any] = {"condition": condition, "replan_prior": weight,
                               "replan_keep": None if keep < 0 else keep, "runs": len(rows)}
        for key in FIGURES:
            values = [r["metrics"].get(f"closed_loop/{key}") for r in rows]
            values = [v for v in values if v is not None]
            row[key] = (round(float(np.mean(values)), 4), round(float(np.std(values, ddof=1)), 4)
                        if len(values) > 1 else None) if values else None
        out.append(row)
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m spade.perf.replanning", description=__doc__.split("\n")[0])
    parser.add_argument("--ckpt", action="append", required=True, help="a student checkpoint (repeat for seeds)")
    parser.add_argument("--weights", type=float, nargs="+", default=[0.0, 0.8, 0.9], help="replan_prior values")
    parser.add_argument("--keep", type=lambda v: None if v.lower() in ("none", "null", "off") else float(v),
                        nargs="+", default=[None], help="replan_keep values (none: off), each on top of every weight")
    parser.add_argument("--conditions", nargs="+", default=list(CONDITIONS), choices=list(CONDITIONS))
    parser.add_argument("--data", default="site_L")
    parser.add_argument("--scale", default="quickstart")
    parser.add_argument("--data-dir", default=None, help="paths.data_dir (where the test set lives)")
    parser.add_argument("--scenarios", type=int, default=None, help="the first N scenarios (default: all)")
    parser.add_argument("--seed", type=int, default=42)
    parser.add_argument("--out", required=True, help="a folder for the JSON records")
    args = parser.parse_args(argv)
    command = "python -m spade.perf.replanning " + " ".join(shlex.quote(a) for a in (argv or sys.argv[1:]))
    records = drive_records(args.ckpt, args.weights, args.conditions, args.data, args.scale, args.scenarios,
                            args.data_dir, args.seed, command, args.keep)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for r in records:
        keep = "" if r["replan_keep"] is None else f"_keep{r['replan_keep']:g}"
        name = f"{r['run']}_{r['condition']}_prior{r['replan_prior']:g}{keep}.json"
        (out / name).write_text(json.dumps(r, indent=1, sort_keys=True) + "\n")
    summary = summarise(records)
    (out / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    for row in summary:
        print(json.dumps(row))


if __name__ == "__main__":
    main()
