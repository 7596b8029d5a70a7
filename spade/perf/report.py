"""The bench's results as Markdown tables (README-ready), the targets of the issue checked, and the JSON file."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

STUDENT_ONNX_TARGET_MS = 15.0  # medium student, batch 1, ONNX Runtime
COND_DBC_RATIO_TARGET = 2.5  # Cond-DBC step / BC step
DDIM_SPEEDUP_TARGET = 10.0  # DDIM-k vs the full DDPM loop ...
DDIM_APE_TOLERANCE = 0.10  # ... at an APE within 10 % of DDPM's


def _table(header: list[str], rows: list[list[Any]]) -> str:
    def cell(v: Any) -> str:
        if isinstance(v, float):
            return f"{v:,.3g}" if abs(v) < 100 else f"{v:,.0f}"
        return str(v)

    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(cell(v) for v in row) + " |" for row in rows]
    return "\n".join(lines)


def check_targets(results: dict[str, Any]) -> list[dict[str, Any]]:
    """The issue's three targets, each with the measured value, whether it is met, and the setting measured."""
    out = []
    for row in results.get("student", []):
        if row["size"] == "medium" and "onnxruntime_b1_ms" in row:
            value = row["onnxruntime_b1_ms"]
            out.append({"target": f"medium student batch-1 ONNX Runtime <= {STUDENT_ONNX_TARGET_MS:g} ms",
                        "setting": f"{row['image_size']} px ({row['gflop_b1']:.2f} GFLOP)", "value": f"{value:.1f} ms",
                        "met": value <= STUDENT_ONNX_TARGET_MS})
    for row in results.get("training", []):
        if row["approach"].startswith("Cond-DBC") and "batch_terms" not in row["approach"]:
            value = row["ratio_to_bc"]
            out.append({"target": f"Cond-DBC step <= {COND_DBC_RATIO_TARGET:g} x BC step",
                        "setting": f"{row['image_size']} px, batch {row['batch_size']}, {row['student']} student, "
                                   f"cond expert {row['expert_preset']}",
                        "value": f"{value:.2f} x", "met": value <= COND_DBC_RATIO_TARGET})
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
        if best is None:
            out.append({"target": f"DDIM >= {DDIM_SPEEDUP_TARGET:g} x faster than DDPM-{ddpm['steps']} at APE within "
                                  f"{DDIM_APE_TOLERANCE:.0%}", "setting": "no DDIM setting within the APE tolerance",
                        "value": "-", "met": False})
        else:
            speedup, row = best
            out.append({"target": f"DDIM >= {DDIM_SPEEDUP_TARGET:g} x faster than DDPM-{ddpm['steps']} at APE within "
                                  f"{DDIM_APE_TOLERANCE:.0%}",
                        "setting": f"DDIM-{row['steps']}: APE {row['ape_cm']:.2f} vs {ddpm['ape_cm']:.2f} cm "
                                   f"({row['samples']} samples)",
                        "value": f"{speedup:.0f} x", "met": speedup >= DDIM_SPEEDUP_TARGET})
    return out


def format_report(results: dict[str, Any]) -> str:
    """All measured sections as Markdown tables, then the targets."""
    parts = []
    m = results.get("machine", {})
    parts.append(f"Machine: {m.get('cpu')} ({m.get('cpu_count')} CPUs), torch {m.get('torch')} with "
                 f"{m.get('torch_threads')} threads, load average {m.get('load_average_1m')} at the start; "
                 f"mode {results.get('mode')}. Times are medians.")
    if results.get("student"):
        rows = results["student"]
        batches = sorted({int(k[len("eager_b"):-3]) for r in rows for k in r if k.startswith("eager_b") and
                          k.endswith("_ms") and "_min" not in k})
        header = ["student", "params", "px", "GFLOP (b1)"]
        for b in batches:
            header += [f"eager b{b} ms", f"ONNX Runtime b{b} ms"]
        table = []
        for r in rows:
            line = [r["size"], f"{r['params']:,}", r["image_size"], r["gflop_b1"]]
            for b in batches:
                line += [r.get(f"eager_b{b}_ms", "-"), r.get(f"onnxruntime_b{b}_ms", "-")]
            table.append(line)
        parts.append("### Student latency\n\n" + _table(header, table))
    if results.get("experts"):
        table = []
        for e in results["experts"]:
            for row in [*e["ddim"], e["ddpm"]]:
                table.append([e["expert"], e["preset"], f"{e['params']:,}", e["image_size"],
                              f"{row['sampler'].upper()}-{row['steps']}", row["seconds_per_sample"],
                              row.get("speedup_vs_ddpm", 1.0),
                              f"extrapolated from {row['timed_steps']} steps" if row["extrapolated"] else "measured"])
        parts.append("### Expert sampling (seconds per sample, batch 1)\n\n" + _table(
            ["expert", "preset", "params", "px", "sampler", "s / sample", "speed-up vs DDPM", "how"], table))
    if results.get("quality"):
        q = results["quality"]
        table = [[f"{r['sampler'].upper()}-{r['steps']}", r["samples"], r["ape_cm"], r["failures"], r["hd_count"],
                  r["seconds_per_sample"]] for r in q["rows"]]
        parts.append(f"### DDIM vs DDPM on a trained expert ({q['expert']})\n\n" + _table(
            ["sampler", "samples", "APE cm", "failures", "Hd19", "s / sample"], table))
    if results.get("training"):
        table = [[r["approach"], r["student"], r["expert_preset"] or "-", r["image_size"], r["batch_size"],
                  r["step_ms"], r["ratio_to_bc"]] for r in results["training"]]
        parts.append("### Training step\n\n" + _table(
            ["approach", "student", "expert", "px", "batch", "ms / step", "x BC"], table))
    if results.get("metrics"):
        r = results["metrics"]
        table = [["APE + Hd19 (update + compute)", r["image_size"], r["ape_hd_instances"],
                  f"{r['ape_hd_instances_per_s']:,.0f} instances/s"],
                 [f"FID ({r['fid_extractor']}){'' if r['fid_computed'] else ', update only'}", r["image_size"],
                  r["fid_images"], f"{r['fid_images_per_s']:,.0f} images/s"]]
        parts.append("### Metrics\n\n" + _table(["metric", "px", "n", "throughput"], table))
    if results.get("data"):
        d = results["data"]
        table = [[f"generation (annotation, preset {g['preset']}, {g['workers']} worker(s))", g["window_px"],
                  g["instances"], f"{g['instances_per_s']:.1f} instances/s"] for g in d.get("generation", [])]
        if d.get("read"):
            r = d["read"]
            table.append(["read: open + sha256", r["image_size"][0], r["instances"], f"{r['open_s'] * 1000:.0f} ms"])
            table.append(["read: item by item", r["image_size"][0], r["instances"], f"{r['items_per_s']:,.0f} instances/s"])
            table.append([f"read: DataLoader, batch {r['loader_batch_size']}", r["image_size"][0], r["instances"],
                          f"{r['loader_instances_per_s']:,.0f} instances/s"])
        parts.append("### Data\n\n" + _table(["what", "px", "instances", "throughput"], table))
    targets = results.get("targets") or check_targets(results)
    if targets:
        table = [[t["target"], t["setting"], t["value"], "met" if t["met"] else "MISSED"] for t in targets]
        parts.append("### Targets\n\n" + _table(["target", "setting", "measured", ""], table))
    return "\n\n".join(parts)


def write_json(results: dict[str, Any], path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(results, indent=2, default=str))
    return path
