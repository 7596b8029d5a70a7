"""The training section's tables (steps, levers, profiles, Lightning's overhead, the evaluation's cost) and the
results page ``docs/results/speed.md`` that ``python -m spade.bench sections=[training] speed_page=...`` writes
from them.

Every figure on the page comes from the results dict of the run that writes it; the prose around them is fixed
or computed from those figures (what the ratio target needs, what bounds it)."""

from __future__ import annotations

import datetime
from pathlib import Path
from typing import Any

from spade.utils.markdown import number_table
from spade.paths import CONFIG_PATH
from spade.perf.targets import RATIO_TARGET, bench_verdict

#: Operator names whose time is the counted (convolution / matmul) work; the rest is what the FLOP counter skips.
_COUNTED = ("conv", "mkldnn", "addmm", "mm", "bmm", "matmul", "linear")


def steps_table(rows: list[dict[str, Any]]) -> str:
    def ratio(r: dict[str, Any], key: str) -> str:
        return f"{r[key]:.2f}" if key in r else "-"

    table = [[r["approach"], r["student"], r.get("expert_preset") or "-", r["image_size"], r["batch_size"],
              r.get("gflop", "-"), r["step_ms"], r.get("steps_per_s", "-"), r.get("gflops", "-"),
              r.get("matmul_gflops", "-"), ratio(r, "ratio_to_matmul"), ratio(r, "ratio_to_bc")] for r in rows]
    return number_table(["step", "student", "expert", "px", "batch", "GFLOP", "ms / step", "steps / s", "GFLOP/s",
                   "matmul GFLOP/s", "x matmul", "x BC"], table)


def levers_table(rows: list[dict[str, Any]]) -> str:
    table = [[r["setup"], r.get("expert_preset") or "-", r["lever"], r["step_ms"], r["steps_per_s"],
              f"{r['speedup']:.2f}", r["gflops"], f"{r['ratio_to_matmul']:.2f}", "yes" if r["loss_finite"] else "NO"]
             for r in rows]
    return number_table(["step", "expert", "lever", "ms / step", "steps / s", "speed-up vs baseline", "GFLOP/s",
                   "x matmul", "loss finite"], table)


def profile_tables(profiles: list[dict[str, Any]]) -> str:
    parts = []
    for p in profiles:
        table = [[o["op"], o["self_cpu_ms"], f"{o['share']:.1%}", o["calls"]] for o in p["operators"]]
        parts.append(f"#### {p['setup']}, {p['lever']} ({p['image_size']} px, batch {p['batch_size']})\n\n"
                     + number_table(["operator", "self CPU ms", "share", "calls"], table))
    return "\n\n".join(parts)


def lightning_table(rows: list[dict[str, Any]]) -> str:
    table = [[r["setting"], r["step_ms"], f"{r['overhead_ms']:+.1f}", f"{r['overhead_ms'] / r['step_ms']:+.1%}"
              if r["step_ms"] else "-", r["steps"]] for r in rows]
    return number_table(["how the BC step runs", "ms / step", "vs bare loop ms", "share", "steps timed"], table)


def evaluation_tables(evaluation: dict[str, Any]) -> str:
    """One test pass and one closed-loop drive (:mod:`spade.perf.evaluation_cost`): ms per part, per instance or
    scenario (and per planning query) and share, each under a line saying what was run."""
    parts = []
    test = evaluation.get("test_pass")
    if test:
        rows = [[r["part"], r["ms"], r["ms_each"], f"{r['share']:.0%}"] for r in test["rows"]]
        parts.append(f"**Test pass**: a fresh {test['student']} student over {test['instances']} synthetic "
                     f"{test['image_size']} px windows, batch {test['batch_size']} (network, the planner's search "
                     "decoder per instance, the metrics, the baselines and references scored beside it).\n\n"
                     + number_table(["part", "ms", "ms / instance", "share"], rows))
    drive = evaluation.get("drive")
    if drive:
        rows = [[r["part"], r["ms"], r["ms_each"], r.get("ms_per_query", "-"), f"{r['share']:.0%}"]
                for r in drive["rows"]]
        parts.append(f"**Closed-loop drive**: the same student's planner drives {drive['scenarios']} L scenarios "
                     f"in a walled room ({drive['image_size']} px windows): {drive['queries']} planning queries, "
                     f"{drive['control_steps']} control steps, {drive['successes']} of {drive['scenarios']} reached "
                     f"the goal; {drive['query_ms']:.1f} ms per query.\n\n"
                     + number_table(["part", "ms", "ms / scenario", "ms / query", "share"], rows))
    return "\n\n".join(parts)


def format_training_speed(speed: dict[str, Any]) -> str:
    """The levers, profiles, Lightning's overhead and the evaluation's cost as Markdown (also part of the bench's
    printed report)."""
    parts = []
    if speed.get("levers"):
        parts.append("### Training levers (each alone, same rounds as its baseline)\n\n"
                     + levers_table(speed["levers"]))
    if speed.get("profiles"):
        parts.append("### Where a step's time goes (torch.profiler, top operators by self CPU time)\n\n"
                     + profile_tables(speed["profiles"]))
    if speed.get("lightning"):
        parts.append("### Lightning's per-step overhead\n\n" + lightning_table(speed["lightning"]))
    if speed.get("evaluation"):
        parts.append("### One test pass and one closed-loop drive: where the time goes\n\n"
                     + evaluation_tables(speed["evaluation"]))
    return "\n\n".join(parts)


def counted_share(operators: list[dict[str, Any]]) -> float:
    """Share of a profiled step's self CPU time (of its top operators) in convolution and matmul kernels."""
    return sum(o["share"] for o in operators if any(k in o["op"].lower() for k in _COUNTED))


def ratio_bound(row: dict[str, Any], share: float) -> float:
    """The step's best ratio to the matmul if its counted work ran at the matmul's rate and the rest (normalisation,
    activations, elementwise, copies, the optimiser: the time outside convolution and matmul kernels) stayed."""
    rest_s = row["step_ms"] / 1000.0 * (1.0 - share)
    ideal_s = row["gflop"] / row["matmul_gflops"]
    return ideal_s / (ideal_s + rest_s)


def _bounds(results: dict[str, Any]) -> str:
    speed = results.get("training_speed") or {}
    profiles = {p["setup"]: p for p in speed.get("profiles", []) if p["lever"] == "baseline"}
    levers = {(r["setup"], r["lever"]): r for r in speed.get("levers", [])}
    lines = []
    for row in results.get("training", []):
        p = profiles.get(row["approach"])
        if p is None or row["image_size"] != p["image_size"]:
            continue
        share = counted_share(p["operators"])
        met = row["ratio_to_matmul"] >= RATIO_TARGET
        lines.append(
            f"- **{row['approach']}** ({row['image_size']} px): {row['ratio_to_matmul']:.2f}x the matmul's rate, "
            f"target {RATIO_TARGET:g}x {'reached' if met else 'NOT reached'}. Convolution and matmul kernels take "
            f"{share:.0%} of its profiled self CPU time; the other {1 - share:.0%} (batch norm, activations, "
            f"elementwise, copies, the optimiser) does work the FLOP counter does not count. Even with the counted "
            f"work at the matmul's rate, that rest caps the step at {ratio_bound(row, share):.2f}x. What bounds it is "
            f"the convolution kernels themselves: oneDNN's convolutions (forward and backward, at these channel "
            f"widths) run the counted work at {row['ratio_to_matmul'] / share if share else 0:.2f}x the matmul's "
            f"rate.")
        for name in ("channels_last", "bf16"):
            lever, base = levers.get((row["approach"], name)), levers.get((row["approach"], "baseline"))
            if lever is not None and base is not None:
                lines[-1] += (f" With {name} (the lever table's rounds): {lever['ratio_to_matmul']:.2f}x, against "
                              f"{base['ratio_to_matmul']:.2f}x for the baseline in the same rounds.")
    return "\n".join(lines)


def _defaults() -> str:
    """What ``trainer=cpu``'s speed options resolve to on this machine."""
    from omegaconf import OmegaConf

    from spade.training.speed import resolve_channels_last, resolve_precision

    cfg = OmegaConf.load(Path(CONFIG_PATH) / "trainer" / "cpu.yaml")
    acc = cfg.get("accelerator", "cpu")
    return (f"`trainer=cpu` on this machine: precision `{cfg.get('precision')}` -> "
            f"`{resolve_precision(cfg.get('precision', '32-true'), acc)}`, channels_last "
            f"`{cfg.get('channels_last')}` -> `{resolve_channels_last(cfg.get('channels_last', False), acc)}`, "
            f"log_every_n_steps "
            f"`{cfg.get('log_every_n_steps')}`.")


def speed_page(results: dict[str, Any], command: str, commit: str | None, wall_s: float,
               date: str | None = None) -> str:
    """The page: the verdict (:func:`~spade.perf.targets.bench_verdict`), provenance, the step table, the levers,
    the bound, the profiles, Lightning's overhead, where a test pass's and a drive's time goes."""
    m = results.get("machine", {})
    speed = results.get("training_speed") or {}
    hw = speed.get("hardware") or {}
    date = date or _now()
    head = [
        "# Training speed",
        "",
        "## Verdict",
        "",
        bench_verdict(results) + " This page times training; what decides a model's quality is stated in the "
        "[metrics reference](../reference/metrics.md#which-figure-decides).",
        "",
        "## How it was measured",
        "",
        "Written by the bench; do not edit by hand. Regenerate with the command below.",
        "",
        f"- Command: `{command}`",
        f"- Commit: `{commit or 'unknown'}`, {date}; wall time {wall_s / 60:.1f} min",
        f"- Machine: {m.get('cpu')} ({m.get('cpu_count')} CPUs; torch CPU capability {hw.get('cpu_capability')}, "
        f"native bf16: {'yes (' + ', '.join(hw.get('cpu_bf16_flags') or []) + ')' if hw.get('cpu_bf16') else 'no'}), "
        f"torch {m.get('torch')} with {m.get('torch_threads')} thread(s), Python {m.get('python')}, load average "
        f"{m.get('load_average_1m')} at the start",
        f"- {_defaults()}",
        "",
        "The machine is shared with other jobs: every comparison is measured in one run, interleaved (one step of "
        "each variant per round, an fp32 "
        f"{speed.get('matmul_size', 1024)}x{speed.get('matmul_size', 1024)} matmul loop timed in every round), and "
        "ratios are medians of per-round ratios. GFLOP: torch's FLOP counter over forward, backward and the AdamW "
        "step (convolutions and matmuls; elementwise work is not counted).",
    ]
    parts = ["\n".join(head)]
    if results.get("training"):
        parts.append("## Steps (baseline: fp32, NCHW, torch's default AdamW)\n\n" + steps_table(results["training"]))
    if speed.get("levers"):
        parts.append("## Levers, each alone against the same run's baseline\n\n" + levers_table(speed["levers"])
                     + "\n\nbf16 (`trainer.precision=bf16-mixed`, or `auto`: bf16-mixed where the CPU or GPU has "
                       "native bf16) changes the numerics: whether it keeps the science (the planner figures of the "
                       "site's BC and teacher-guided rows, bf16 against fp32 over seeds) is the "
                       "[precision page](precision.md)'s verdict.")
    bounds = _bounds(results)
    if bounds:
        parts.append("## What bounds the ratio to the matmul\n\n" + bounds)
    if speed.get("profiles"):
        parts.append("## Where a step's time goes (torch.profiler, top operators by self CPU time)\n\n"
                     + profile_tables(speed["profiles"]))
    if speed.get("lightning"):
        parts.append("## Lightning's per-step overhead (BC step inside `Trainer.fit`, CSV logger)\n\n"
                     + lightning_table(speed["lightning"])
                     + "\n\nThe settings run one after another (each a short `Trainer.fit`), not interleaved step by "
                       "step: a change of the machine's load between them moves these rows as much as the setting "
                       "does; the bare loop and the fits share a median, not a round.")
    if speed.get("evaluation"):
        parts.append("## One test pass and one closed-loop drive: where the time goes\n\n"
                     "Random weights (the cost does not depend on their values); each part clocked where it runs "
                     "during the one pass (spade/perf/evaluation_cost.py), so the parts add up to the total.\n\n"
                     + evaluation_tables(speed["evaluation"]))
    return "\n\n".join(parts) + "\n"


def _now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")


def write_speed_page(results: dict[str, Any], path: str | Path, command: str, commit: str | None,
                     wall_s: float) -> Path:
    """The page at ``path`` and, beside it (``.json``), the results and provenance it was written from."""
    import json

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    provenance = {"command": command, "commit": commit, "wall_s": wall_s, "date": _now()}
    path.with_suffix(".json").write_text(json.dumps({"provenance": provenance, "results": results}, indent=1,
                                                    default=str))
    path.write_text(speed_page(results, command, commit, wall_s, provenance["date"]))
    return path


def rerender(json_path: str | Path) -> Path:
    """The page of ``json_path`` (what :func:`write_speed_page` wrote beside it) written again by this code from the
    recorded figures and provenance, without measuring again."""
    import json

    json_path = Path(json_path)
    data = json.loads(json_path.read_text())
    results, p = data["results"], data["provenance"]
    results.pop("speed_science", None)  # written by an earlier bf16 check, now the precision page's
    page = json_path.with_suffix(".md")
    page.write_text(speed_page(results, p["command"], p["commit"], p["wall_s"], p["date"]))
    return page


if __name__ == "__main__":
    import sys

    if len(sys.argv) != 2:
        raise SystemExit("usage: python -m spade.perf.speed_page docs/results/speed.json")
    print(rerender(sys.argv[1]))
