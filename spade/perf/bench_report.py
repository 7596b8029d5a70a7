"""The bench's results as Markdown tables (README-ready), led by the verdict on its performance targets
(:mod:`spade.perf.targets`), and the JSON file."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from spade.metrics import catalog
from spade.utils.markdown import number_table
from spade.perf.contention import format_contention
from spade.perf.speed_page import format_training_speed, steps_table
from spade.perf.targets import bench_verdict, check_targets

def format_report(results: dict[str, Any]) -> str:
    """The verdict (:func:`~spade.perf.targets.bench_verdict`), then all measured sections as Markdown tables,
    then the targets."""
    parts = [bench_verdict(results)]
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
        parts.append("### Student latency\n\n" + number_table(header, table))
    if results.get("experts"):
        table = []
        for e in results["experts"]:
            for row in [*e["ddim"], e["ddpm"]]:
                table.append([e["expert"], e["preset"], f"{e['params']:,}", e["image_size"],
                              f"{row['sampler'].upper()}-{row['steps']}", row["seconds_per_sample"],
                              row.get("speedup_vs_ddpm", 1.0),
                              f"extrapolated from {row['timed_steps']} steps" if row["extrapolated"] else "measured"])
        parts.append("### Expert sampling (seconds per sample, batch 1)\n\n" + number_table(
            ["expert", "preset", "params", "px", "sampler", "s / sample", "speed-up vs DDPM", "how"], table))
    if results.get("quality"):
        q = results["quality"]
        table = [[f"{r['sampler'].upper()}-{r['steps']}", r["samples"], r["ape_cm"], r["failures"], r["hd_count"],
                  r["seconds_per_sample"]] for r in q["rows"]]
        parts.append(f"### DDIM vs DDPM on a trained expert ({q['expert']})\n\n" + number_table(
            ["sampler", "samples", *map(catalog.label, ("ape_cm", "failures", "hd19", "seconds_per_sample"))], table))
    if results.get("decoder"):
        table = [[r["decoder"], r["image_size"], r["instances"], r["median_ms"], r["p95_ms"], r["cpu_ms_per_instance"]]
                 for r in results["decoder"]]
        parts.append("### Path decoding per instance (the planner's search vs the paper's skeleton extraction)\n\n"
                     + number_table(["decoder", "px", "instances", "median ms", "p95 ms", "CPU ms / instance"], table))
    if results.get("training"):
        parts.append("### Training step\n\n" + steps_table(results["training"]))
    if results.get("training_speed") and format_training_speed(results["training_speed"]):
        parts.append(format_training_speed(results["training_speed"]))
    if results.get("metrics"):
        parts.append(_metrics(results["metrics"]))
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
        parts.append("### Data\n\n" + number_table(["what", "px", "instances", "throughput"], table))
    if results.get("annotation_scaling"):
        parts.append(_annotation_scaling(results["annotation_scaling"]))
    if results.get("closed_loop"):
        k = results["closed_loop"]
        parts.append("### Closed loop (seconds; spade/perf/closed_loop.py)\n\n" + number_table(
            ["scenarios", "student plans", "student drive", "network", "decoding", "rest (windows, following)",
             "shortest", "heading", "all", "scenarios / s (student)"],
            [[k["scenarios"], k["plans"], k["student_s"], k["network_s"], k["decoding_s"], k["rest_s"],
              k.get("shortest_s", "-"), k.get("heading_s", "-"), k["all_s"], k["scenarios_per_s"]]]))
    if results.get("contention"):
        parts.append("### " + format_contention(results["contention"]["rows"], results["contention"]["size"]))
    if results.get("annotation"):
        parts.append(_annotation(results["annotation"]))
    if results.get("dataset"):
        parts.append(_dataset(results["dataset"]))
    if results.get("maps"):
        parts.append(_maps(results["maps"]))
    targets = results.get("targets") or check_targets(results)
    if targets:
        table = [[t["target"], t["setting"], t["value"], "met" if t["met"] else "MISSED"] for t in targets]
        parts.append("### Targets\n\n" + number_table(["target", "setting", "measured", ""], table))
    return "\n\n".join(parts)


def _metrics(r: dict[str, Any]) -> str:
    px = r["image_size"]
    table = [["APE + Hd19 (update + compute)", px, r["ape_hd_instances"],
              f"{r['ape_hd_instances_per_s']:,.0f} instances/s"]]
    ref, loops = r.get("reference") or {}, r.get("reference_loops")
    if ref.get("instances"):
        table.append(["reference: thin, dense adjacency, all-pairs shortest paths, evo; directed_hausdorff", px,
                      ref["instances"], f"{1e3 / ref['ms_per_instance']:,.0f} instances/s "
                                        f"(spade.metrics {ref['speedup']:.1f}x faster)"])
    if loops:
        table.append(["reference with SKIPP's Python adjacency loops", px, loops["instances"],
                      f"{1e3 / loops['ms_per_instance']:,.1f} instances/s "
                      f"(spade.metrics {loops['slowdown']:.0f}x faster)"])
    table.append([f"FID ({r['fid_extractor']}){'' if r['fid_computed'] else ', update only'}", px, r["fid_images"],
                  f"{r['fid_images_per_s']:,.0f} images/s"])
    out = "### Metrics\n\n" + number_table(["metric", "px", "n", "throughput"], table)
    if ref.get("instances"):
        out += (f"\n\nSame {ref['instances']} instances: APE mean {ref['ours_ape_mean_cm']:.3f} cm (median "
                f"{ref['ours_ape_median_cm']:.3f}, failures {ref['ours_failures']}) vs the reference's "
                f"{ref['ape_mean_cm']:.3f} cm (median {ref['ape_median_cm']:.3f}, failures {ref['failures']}); "
                f"Hausdorff max |diff| {ref['hd_max_abs_diff_px']:.2e} px, empty flags equal: "
                f"{ref['hd_empty_flags_equal']}.")
    elif ref.get("skipped"):
        out += f"\n\nReference pipeline skipped: {ref['skipped']}."
    if r.get("sensitivity"):
        sens = r["sensitivity"]
        rows = [[f"{row['extractor']} (D={row['feature_dim']})", row["kind"],
                 ", ".join(f"{v:g}" for v in row["levels"]),
                 " ".join(f"{v:.4g}" for v in row["fid"]), f"{row['ratio']:.1f}",
                 "yes" if row["monotonic"] else "NO"] for row in sens["rows"]]
        out += (f"\n\n### FID sensitivity ({sens['images']} real vs {sens['images']} generated {sens['image_size']} px "
                f"paths, degraded)\n\n" + number_table(["extractor", "degradation", "levels", catalog.label("fid"),
                                                  "last / first", "monotonic"], rows))
    if r.get("shape_validity"):
        sv = r["shape_validity"]
        rows = [[f"{row['extractor']} (D={row['feature_dim']})", s["set"], f"{s['fid']:.4g}", f"{s['ratio']:.1f}"]
                for row in sv["rows"] for s in row["sets"]]
        rows += [[f"{row['extractor']} (D={row['feature_dim']})",
                  f"{g['kind']} " + ", ".join(f"{v:g}" for v in g["levels"]),
                  " ".join(f"{v:.4g}" for v in g["fid"]), "monotonic" if g["monotonic"] else "NOT monotonic"]
                 for row in sv["rows"] for g in row["growing"]]
        out += (f"\n\n### FID shape validity ({sv['images']} robot-frame L paths vs {sv['images']} per set, "
                f"{sv['image_size']} px)\n\n"
                + number_table(["extractor", "set", catalog.label("fid"), "/ ground truth"], rows))
    if r.get("fid_table"):
        ft = r["fid_table"]
        names = list(ft["columns"][0]["fid"])
        rows = [[name, ft["counts"][name]] + [f"{c['fid'][name]:.4g}" if c["fid"][name] is not None
                                              else f"- (needs > {c['feature_dim']} images)" for c in ft["columns"]]
                for name in names]
        out += (f"\n\n### FID against the test set's ground truth ({ft['test_dir']}, {ft['shape'] or 'all'} "
                f"instances: {ft['real']}; resample: {ft['resample']})\n\n"
                + number_table(["generated set", "n"] + [f"FID ({c['extractor']})" for c in ft["columns"]], rows))
    return out


def _annotation(a: dict[str, Any]) -> str:
    table = []
    for r in a["presets"]:
        rates = ", ".join(f"{k} {v:.1%}" for k, v in r["rejection_rates"].items()) or "-"
        table.append([r["preset"], r["window_px"], r["workers"], r["instances"], r["seconds"],
                      f"{r['instances_per_s']:.1f}", f"{r['scenarios_accepted']} / {r['scenarios_tried']}", rates,
                      r["failed_scenarios"]])
    table.append(["total", "", "", a["instances"], a["seconds"], f"{a['instances_per_s']:.1f}", "", "", ""])
    return (f"### Annotation ({a['maps']})\n\n"
            + number_table(["preset", "px", "workers", "instances", "s", "instances/s", "scenarios accepted / tried",
                      "rejections (of attempts)", "failed scenarios"], table))


def _annotation_scaling(a: dict[str, Any]) -> str:
    table = [[r["window_px"], r["resolution_m"], r["workers"], r["instances"], r["scenarios"], f"{r['seconds']:.1f}",
              f"{r['startup_s']:.1f}", f"{r['instances_per_s']:.1f}", f"{r['instances_per_s_per_worker']:.1f}",
              f"{r['instances_per_s_per_worker_after_startup']:.1f}", f"{r['instances_per_cpu_s']:.1f}",
              f"{r['load_average_1m']:.1f}" if "load_average_1m" in r else "-",
              "yes" if r["same_as_first"] else "NO"] for r in a["rows"]]
    spt = a.get("states_per_task") or "the tool's default"
    return (f"### Annotation scaling (preset {a['preset']}, {a['maps']}; states per task: {spt})\n\n"
            + number_table(["px", "m/px", "workers", "instances", "scenarios", "s", "pool start-up s", "instances/s",
                      "instances/s per worker", "per worker without start-up", "instances per CPU-s", "load 1m",
                      "same dataset as the first"], table)
            + "\n\nPool start-up: starting the workers and importing their modules, measured apart; CPU seconds: "
              "this process and its workers (start-up included), a figure that other jobs on the machine change "
              "less than the wall clock; load 1m: the machine's load average when the row started.")


def _dataset(d: dict[str, Any]) -> str:
    n, px = d["instances"], d["image_size"][0]
    table = [["open: manifest + sha256", f"{d['open_s'] * 1000:,.0f} ms"],
             ["one pass, item by item", f"{d['items_per_s']:,.0f} instances/s"],
             [f"one pass, DataLoader batch {d['loader_batch_size']}",
              f"{d['loader_instances_per_s']:,.0f} instances/s"],
             ["resident memory: after the imports / peak / for the dataset",
              f"{d['rss_baseline_mb']:,.0f} / {d['rss_peak_mb']:,.0f} / +{d['rss_dataset_mb']:,.0f} MB"]]
    if "write_s" in d:
        table.insert(0, ["written (synthetic)", f"{d['write_s']:.1f} s"])
    return (f"### Dataset read ({n:,} instances of {px} px, {d['disk_mib']:,.1f} MiB, one fresh process)\n\n"
            + number_table(["what", "figure"], table))


def _maps(m: dict[str, Any]) -> str:
    parts = []
    if m.get("real"):
        to = m["real"][0]["resample_to_m"]
        table = [[r["map"], f"{r['width']} x {r['height']}", r["resolution_m"], r["occupied"], r["free"],
                  r["unknown"], r["load_ms"], r["resample_ms"], r["clear_square_m"]] for r in m["real"]]
        parts.append(f"### Real maps ({m['dir']})\n\n" + number_table(
            ["map", "W x H", "m/px", "occupied", "free", "unknown", "load ms", f"-> {to:g} m/px ms",
             "clear square m"], table))
    else:
        parts.append(f"Real maps: none ({'no folder given' if not m.get('dir') else m['dir'] + ' is not a folder'}; "
                     "set maps.dir or SPADE_MAPS_DIR)")
    rows = m["procedural"]
    table = [[r["kind"], f"{r['width']} x {r['height']}", r["generate_ms"], r["occupied"], r["free"], r["unknown"],
              r["min_clear_square_m"], r["min_reach"]] for r in rows]
    seeds = rows[0]["seeds"] if rows else 0
    parts.append(f"### Procedural maps (0.05 m/px, seeds 0-{seeds - 1}, means; worst case of the last two)\n\n"
                 + number_table(["kind", "W x H", "generate ms", "occupied", "free", "unknown", "clear square m",
                           "reach"], table))
    return "\n\n".join(parts)


def write_json(results: dict[str, Any], path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(results, indent=2, default=str))
    return path
