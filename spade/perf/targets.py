"""The bench's performance targets, checked against the measured figures, and the verdict its pages open with.

:func:`check_targets` judges each target the results measured (the medium student's latency, a Cond-DBC step against
a BC step, closed-loop driving, DDIM's speed-up at DDPM's APE); :func:`bench_verdict` says in two or three sentences
what they came to, and how near the training steps run to the machine's matmul rate (:data:`RATIO_TARGET`). Both
the bench's report (:mod:`spade.perf.bench_report`) and the training-speed page (:mod:`spade.perf.speed_page`) lead
with it; the docs' results index quotes its first sentence.
"""

from __future__ import annotations

from typing import Any

__all__ = ["CLOSED_LOOP_TARGET_S", "COND_DBC_RATIO_TARGET", "DDIM_APE_TOLERANCE", "DDIM_SPEEDUP_TARGET",
           "RATIO_TARGET", "STUDENT_ONNX_TARGET_MS", "bench_verdict", "check_targets"]

STUDENT_ONNX_TARGET_MS = 15.0  # medium student, batch 1, ONNX Runtime
COND_DBC_RATIO_TARGET = 2.5  # Cond-DBC step / BC step
DDIM_SPEEDUP_TARGET = 10.0  # DDIM-k vs the full DDPM loop ...
CLOSED_LOOP_TARGET_S = 120.0  # 100 quickstart test scenarios driven in closed loop, student and baselines, 2 cores
DDIM_APE_TOLERANCE = 0.10  # ... at an APE within 10 % of DDPM's
#: A training step's FLOP rate at least this share of the same run's fp32 matmul rate.
RATIO_TARGET = 0.6


def check_targets(results: dict[str, Any]) -> list[dict[str, Any]]:
    """The bench's performance targets, each with the measured value, whether it is met, the setting measured and
    ``finding``: the clause a verdict says of it (the measured figure against the target, in words)."""
    out = []
    for row in results.get("student", []):
        if row["size"] == "medium" and "onnxruntime_b1_ms" in row:
            value = row["onnxruntime_b1_ms"]
            met = value <= STUDENT_ONNX_TARGET_MS
            out.append({"target": f"medium student batch-1 ONNX Runtime <= {STUDENT_ONNX_TARGET_MS:g} ms",
                        "setting": f"{row['image_size']} px ({row['gflop_b1']:.2f} GFLOP)", "value": f"{value:.1f} ms",
                        "met": met,
                        "finding": f"the medium student plans in {value:.1f} ms (batch 1, ONNX Runtime, "
                                   f"{row['image_size']} px), {'within' if met else 'over'} the "
                                   f"{STUDENT_ONNX_TARGET_MS:g} ms target"})
    for row in results.get("training", []):
        if row["approach"].startswith("Cond-DBC") and "batch_terms" not in row["approach"] and "ratio_to_bc" in row:
            value = row["ratio_to_bc"]
            met = value <= COND_DBC_RATIO_TARGET
            out.append({"target": f"Cond-DBC step <= {COND_DBC_RATIO_TARGET:g} x BC step",
                        "setting": f"{row['image_size']} px, batch {row['batch_size']}, {row['student']} student, "
                                   f"cond expert {row['expert_preset']}",
                        "value": f"{value:.2f} x", "met": met,
                        "finding": f"a Cond-DBC training step ({row['student']} student, {row['image_size']} px) "
                                   f"takes {value:.2f}x a BC step, {'within' if met else 'over'} the "
                                   f"{COND_DBC_RATIO_TARGET:g}x target"})
    loop = results.get("closed_loop")
    if loop:
        per100 = loop["all_s"] * 100.0 / max(loop["scenarios"], 1)
        met = per100 <= CLOSED_LOOP_TARGET_S
        out.append({"target": f"100 closed-loop scenarios (student and baselines) <= {CLOSED_LOOP_TARGET_S:g} s",
                    "setting": f"{loop['scenarios']} scenarios of {loop['dataset']}, {loop['plans']} student plans",
                    "value": f"{per100:.1f} s per 100", "met": met,
                    "finding": f"100 closed-loop scenarios drive in {per100:.0f} s, {'within' if met else 'over'} "
                               f"the {CLOSED_LOOP_TARGET_S:g} s target"})
    quality = results.get("quality") or {}
    rows = quality.get("rows") or []
    ddpm = next((r for r in rows if r["sampler"] == "ddpm"), None)
    if ddpm is not None:
        best = None
        for row in rows:
            if row["sampler"] != "ddim":
                continue
            speedup = ddpm["seconds_per_sample"] / row["seconds_per_sample"]
            within = row["ape_cm"] <= ddpm["ape_cm"] * (1 + DDIM_APE_TOLERANCE)
            if within and (best is None or speedup > best[0]):
                best = (speedup, row)
        target = (f"DDIM >= {DDIM_SPEEDUP_TARGET:g} x faster than DDPM-{ddpm['steps']} at APE within "
                  f"{DDIM_APE_TOLERANCE:.0%}")
        if best is None:
            out.append({"target": target, "setting": "no DDIM setting within the APE tolerance", "value": "-",
                        "met": False,
                        "finding": f"no DDIM setting keeps the APE within {DDIM_APE_TOLERANCE:.0%} of "
                                   f"DDPM-{ddpm['steps']}'s, missing the {DDIM_SPEEDUP_TARGET:g}x speed-up target"})
        else:
            speedup, row = best
            met = speedup >= DDIM_SPEEDUP_TARGET
            out.append({"target": target,
                        "setting": f"DDIM-{row['steps']}: APE {row['ape_cm']:.2f} vs {ddpm['ape_cm']:.2f} cm "
                                   f"({row['samples']} samples)",
                        "value": f"{speedup:.0f} x", "met": met,
                        "finding": f"DDIM-{row['steps']} samples {speedup:.0f}x faster than DDPM-{ddpm['steps']} at "
                                   f"an APE within {DDIM_APE_TOLERANCE:.0%}, {'meeting' if met else 'short of'} "
                                   f"the {DDIM_SPEEDUP_TARGET:g}x target"})
    return out


def _matmul_sentence(results: dict[str, Any]) -> str:
    """How near the training steps run to the same run's fp32 matmul rate, against :data:`RATIO_TARGET`."""
    ratios = {r["approach"]: r["ratio_to_matmul"] for r in results.get("training", []) if "ratio_to_matmul" in r}
    if not ratios:
        return ""
    reached = [a for a, r in ratios.items() if r >= RATIO_TARGET]
    low, high = min(ratios.values()), max(ratios.values())
    span = f"{low:.2f}x" if low == high else f"{low:.2f}x to {high:.2f}x"
    if len(reached) == len(ratios):
        judged = f"every step reaches the {RATIO_TARGET:g}x target"
    elif not reached:
        judged = f"none reaches the {RATIO_TARGET:g}x target"
    else:
        judged = (f"{', '.join(reached)} reach{'es' if len(reached) == 1 else ''} the {RATIO_TARGET:g}x target, "
                  f"the other {len(ratios) - len(reached)} do not")
    return f"The training steps run at {span} the rate of an fp32 matmul on the same CPU: {judged}."


def bench_verdict(results: dict[str, Any]) -> str:
    """Two or three sentences from the measured figures: how many targets were met on this CPU and each target's
    finding (:func:`check_targets`), then the training steps against the matmul rate."""
    targets = check_targets(results)
    cpu = (results.get("machine") or {}).get("cpu")
    where = f"this CPU ({cpu})" if cpu else "this machine"
    if targets:
        met = sum(t["met"] for t in targets)
        first = (f"{met} of {len(targets)} performance target{'s' if len(targets) > 1 else ''} met on {where}: "
                 + "; ".join(t["finding"] for t in targets) + ".")
    else:
        first = f"No performance target was measured by this run on {where}; its figures are below."
    matmul = _matmul_sentence(results)
    return first + (f" {matmul}" if matmul else "")
