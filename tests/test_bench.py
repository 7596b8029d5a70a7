"""``python -m spade.bench``: quick mode runs every section end to end (the default ones, then the components'
sections); the targets are judged as stated."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from spade.perf.bench_report import format_report
from spade.perf.targets import bench_verdict, check_targets

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.slow  # a python -m spade.bench process; targets and config: the fast tests below
def test_quick_bench_measures_the_default_sections(tmp_path: Path) -> None:
    pytest.importorskip("onnxruntime")
    out = tmp_path / "bench.json"
    env = {**os.environ, "SPADE_HOME": str(tmp_path / "home")}
    cmd = [sys.executable, "-m", "spade.bench", "quick=true", f"out_json={out}"]
    proc = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-4000:]
    results = json.loads(out.read_text())
    assert results["mode"] == "quick" and results["machine"]["torch_threads"] == 1

    (student,) = results["student"]
    for key in ("eager_b1_ms", "onnxruntime_b1_ms", "eager_b2_ms", "onnxruntime_b2_ms", "gflop_b1"):
        assert student[key] > 0
    assert {e["expert"] for e in results["experts"]} == {"cond", "uncond"}
    for e in results["experts"]:
        assert e["params"] > 0 and e["ddpm"]["steps"] == 1000 and e["ddpm"]["extrapolated"]
        assert all(r["seconds_per_sample"] > 0 and r["speedup_vs_ddpm"] > 1 for r in e["ddim"])
    approaches = [r["approach"] for r in results["training"]]
    assert approaches == ["BC", "DBC", "Cond-DBC", "Cond-DBC (batch_terms)", "Expert (cond tiny)"]
    assert results["training"][0]["ratio_to_bc"] == 1.0 and all(r["step_ms"] > 0 for r in results["training"])
    assert all(r["gflop"] > 0 and r["ratio_to_matmul"] > 0 for r in results["training"])
    speed = results["training_speed"]
    assert {r["lever"] for r in speed["levers"]} >= {"baseline", "channels_last", "bf16", "fused"}
    assert all(r["loss_finite"] for r in speed["levers"]) and len(speed["profiles"]) == 4
    assert [r["setting"] for r in speed["lightning"]][0] == "bare loop"
    assert results["metrics"]["ape_hd_instances_per_s"] > 0 and results["metrics"]["fid_images_per_s"] > 0
    assert not {"annotation", "dataset", "maps"} & set(results)  # the components' sections run when named
    assert [g["preset"] for g in results["data"]["generation"]] == ["lshape", "test"]
    assert results["data"]["read"]["instances"] == results["data"]["generation"][0]["instances"] > 0
    rows = results["quality"]["rows"]
    assert [(r["sampler"], r["steps"]) for r in rows] == [("ddim", 2), ("ddim", 5), ("ddpm", 50)]
    assert all(r["samples"] == 4 and r["seconds_per_sample"] > 0 for r in rows)
    assert any(t["target"].startswith("Cond-DBC") for t in results["targets"])
    scaling = results["annotation_scaling"]["rows"]
    assert [(r["window_px"], r["workers"]) for r in scaling] == [(64, 1), (64, 2)]
    assert all(r["instances"] == 16 and r["instances_per_s_per_worker"] > 0 and r["same_as_first"] for r in scaling)

    for heading in ("Student latency", "Expert sampling", "DDIM vs DDPM", "Training step", "Metrics", "Data",
                    "Annotation scaling", "Targets"):
        assert f"### {heading}" in proc.stdout


@pytest.mark.slow  # a python -m spade.bench process
def test_component_sections_run_at_tiny_sizes(tmp_path: Path) -> None:
    """annotation, dataset and maps (named in ``sections``) and the metrics section's reference pipeline and FID
    sensitivity run at tiny sizes, print their tables and write their numbers."""
    from spade.maps import generate_map, save_ros_map

    maps_dir = tmp_path / "maps"
    maps_dir.mkdir()
    save_ros_map(generate_map("warehouse", 1), maps_dir / "warehouse_1.yaml")
    out = tmp_path / "bench.json"
    env = {**os.environ, "SPADE_HOME": str(tmp_path / "home")}
    cmd = [sys.executable, "-m", "spade.bench", "quick=true", f"out_json={out}",
           "sections=[metrics,annotation,dataset,maps]", "metrics.sensitivity=true",
           "metrics.sensitivity_images=250", "metrics.sensitivity_image_size=32", f"maps.dir={maps_dir}"]
    proc = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-4000:]
    results = json.loads(out.read_text())
    assert set(results) >= {"metrics", "annotation", "dataset", "maps"} and "student" not in results

    m = results["metrics"]
    assert m["ape_hd_instances"] == 32 and m["ape_hd_instances_per_s"] > 0 and m["fid_images_per_s"] > 0
    if "skipped" not in m["reference"]:  # evo (the dev extra) present
        assert m["reference"]["instances"] == 4 and m["reference"]["speedup"] > 0
        assert m["reference_loops"]["instances"] == 2 and m["reference_loops"]["ms_per_instance"] > 0
    sens = m["sensitivity"]
    assert len(sens["rows"]) == 5 * 4 and all(len(r["fid"]) == len(r["levels"]) == 5 for r in sens["rows"])
    shape_rows = m["shape_validity"]["rows"]
    assert [r["extractor"].split("_")[0] for r in shape_rows] == ["shape-v1", "randconv-v2"]
    assert all(len(r["sets"]) == 6 and len(r["growing"]) == 3 for r in shape_rows)

    (preset,) = results["annotation"]["presets"]
    assert preset["preset"] == "lshape" and preset["instances"] == 8 and preset["instances_per_s"] > 0
    assert preset["scenarios_accepted"] > 0 and all(0 <= v <= 1 for v in preset["rejection_rates"].values())

    d = results["dataset"]
    assert d["instances"] == 64 and d["image_size"] == [32, 32] and d["write_s"] > 0 and d["items_per_s"] > 0
    assert d["rss_peak_mb"] >= d["rss_baseline_mb"] > 0

    (real,) = results["maps"]["real"]
    assert real["map"] and real["load_ms"] > 0 and real["resample_ms"] >= 0 and real["clear_square_m"] > 0
    procedural = results["maps"]["procedural"]
    assert procedural and all(r["seeds"] == 1 and r["generate_ms"] > 0 for r in procedural)

    for heading in ("Metrics", "FID sensitivity", "FID shape validity", "Annotation", "Dataset read", "Real maps", "Procedural maps"):
        assert f"### {heading}" in proc.stdout
    assert "Same 4 instances" in proc.stdout or "Reference pipeline skipped" in proc.stdout


def _results(onnx_ms: float, cond_ratio: float, ddim: list[tuple[int, float, float]]) -> dict:
    """Bench results with one medium student row, BC / Cond-DBC rows and DDIM rows (steps, APE, s) vs DDPM (1.0 cm, 10 s)."""
    quality = [{"sampler": "ddim", "steps": k, "ape_cm": ape, "seconds_per_sample": s, "samples": 8,
                "failures": 0, "hd_count": 0}
               for k, ape, s in ddim]
    quality.append({"sampler": "ddpm", "steps": 1000, "ape_cm": 1.0, "seconds_per_sample": 10.0, "samples": 8,
                    "failures": 0, "hd_count": 0})
    training = [{"approach": a, "student": "medium", "expert_preset": p, "image_size": 64, "batch_size": 32,
                 "step_ms": 100.0 * r, "ratio_to_bc": r}
                for a, p, r in (("BC", None, 1.0), ("Cond-DBC", "paper", cond_ratio),
                                ("Cond-DBC (batch_terms)", "paper", 99.0))]
    return {"student": [{"size": "medium", "image_size": 128, "params": 1, "gflop_b1": 3.8, "eager_b1_ms": 40.0,
                         "onnxruntime_b1_ms": onnx_ms}],
            "training": training, "quality": {"expert": "x", "rows": quality}}


def test_targets_are_judged_as_the_issue_states() -> None:
    met = check_targets(_results(14.0, 2.4, [(10, 1.5, 0.1), (50, 1.08, 0.5), (100, 1.0, 1.2)]))
    assert [t["met"] for t in met] == [True, True, True]
    assert met[2]["value"] == "20 x" and "DDIM-50" in met[2]["setting"]  # fastest DDIM within 10 % of DDPM's APE
    missed = check_targets(_results(16.0, 2.6, [(10, 1.5, 0.1), (100, 1.05, 1.2)]))
    assert [t["met"] for t in missed] == [False, False, False]  # DDIM-100 is within 10 % but only 8x faster
    assert "batch_terms" not in " ".join(t["setting"] for t in missed)
    none_within = check_targets(_results(10.0, 2.0, [(10, 1.5, 0.1)]))
    assert none_within[2]["met"] is False and none_within[2]["value"] == "-"
    table = format_report({"mode": "full", "machine": {}, **_results(14.0, 2.4, [(10, 1.05, 0.1)])})
    assert "| medium student batch-1 ONNX Runtime <= 15 ms |" in table and "MISSED" not in table


def test_the_verdict_says_from_the_measured_figures_whether_the_targets_were_met() -> None:
    met = {"machine": {"cpu": "AMD EPYC"}, **_results(14.0, 2.4, [(50, 1.08, 0.5)])}
    for row, ratio in zip(met["training"], (0.65, 0.7, 0.61)):
        row["ratio_to_matmul"] = ratio
    verdict = bench_verdict(met)
    first, rest = verdict.split(". ", 1)
    assert first.startswith("3 of 3 performance targets met on this CPU (AMD EPYC): the medium student plans in "
                            "14.0 ms (batch 1, ONNX Runtime, 128 px), within the 15 ms target;")
    assert "takes 2.40x a BC step, within the 2.5x target" in first and "20x faster" in first
    assert rest == "The training steps run at 0.61x to 0.70x the rate of an fp32 matmul on the same CPU: every step " \
                   "reaches the 0.6x target."
    missed = {"machine": {}, **_results(16.0, 2.6, [(10, 1.5, 0.1)])}
    for row, ratio in zip(missed["training"], (0.53, 0.52, 0.44)):
        row["ratio_to_matmul"] = ratio
    verdict = bench_verdict(missed)
    assert verdict.startswith("0 of 3 performance targets met on this machine: the medium student plans in 16.0 ms")
    assert "over the 15 ms target" in verdict and "takes 2.60x a BC step, over the 2.5x target" in verdict
    assert "no DDIM setting keeps the APE within 10% of DDPM-1000" in verdict and "none reaches the 0.6x target" in verdict
    assert bench_verdict({}).startswith("No performance target was measured")
    assert format_report(met).startswith(bench_verdict(met))  # the report leads with it


def test_quick_and_full_settings_come_from_one_config() -> None:
    import spade.bench  # noqa: F401  (registers the quick_or resolver)
    from spade.utils.config import compose_config

    full = compose_config("bench", [])
    quick = compose_config("bench", ["quick=true", "student.runs=7"])
    assert list(full.student.sizes) == ["small", "medium", "large"] and full.experts.cond_preset == "paper"
    assert list(quick.student.sizes) == ["small"] and quick.experts.cond_preset == "tiny"
    assert full.annotation.num_instances is None and quick.dataset.instances == 64 and full.maps.seeds == 10
    assert quick.student.runs == 7 and quick.threads == 1 and full.threads is None


def _scaling_row(px: int, workers: int, seconds: float, same: bool = True) -> dict:
    return {"preset": "test", "window_px": px, "resolution_m": 6.4 / px, "workers": workers, "instances": 256,
            "scenarios": 4, "seconds": seconds, "instances_per_s": 256 / seconds,
            "instances_per_s_per_worker": 256 / seconds / workers, "startup_s": 0.0 if workers == 1 else 3.0,
            "instances_per_s_per_worker_after_startup": 256 / (seconds - (0 if workers == 1 else 3.0)) / workers,
            "cpu_s": seconds * workers, "instances_per_cpu_s": 256 / (seconds * workers), "load_average_1m": 1.5,
            "dataset_sha256": "x",
            "same_as_first": same}


def test_annotation_scaling_is_a_default_section_at_64_and_128_px_with_1_and_2_workers() -> None:
    import spade.bench  # noqa: F401  (registers the quick_or resolver)
    from spade.utils.config import compose_config

    full = compose_config("bench", [])
    assert "annotation_scaling" in full.sections and full.annotation_scaling.preset == "test"
    assert list(full.annotation_scaling.image_sizes) == [64, 128] and list(full.annotation_scaling.workers) == [1, 2]
    assert full.annotation_scaling.num_instances == 256
    quick = compose_config("bench", ["quick=true"])
    assert list(quick.annotation_scaling.image_sizes) == [64] and quick.annotation_scaling.num_instances == 16
    rows = [_scaling_row(64, 1, 4.0), _scaling_row(64, 2, 5.0), _scaling_row(128, 1, 8.0),
            _scaling_row(128, 2, 7.0, same=False)]
    table = format_report({"mode": "full", "machine": {}, "annotation_scaling": {
        "preset": "test", "maps": "the preset's procedural map", "states_per_task": None, "rows": rows}})
    assert "### Annotation scaling (preset test" in table and "instances/s per worker" in table
    assert "| 128 | 0.05 | 2 | 256 | 4 | 7.0 | 3.0 | 36.6 | 18.3 | 32.0 | 18.3 | 1.5 | NO |" in table
    assert "| 64 | 0.1 | 1 | 256 | 4 | 4.0 | 0.0 | 64.0 | 64.0 | 64.0 | 64.0 | 1.5 | yes |" in table


def test_unknown_sections_are_refused() -> None:
    from spade.bench import bench
    from spade.utils.config import compose_config

    with pytest.raises(ValueError, match="unknown bench sections"):
        bench(compose_config("bench", ["quick=true", "sections=[student,gpu]"]))


@pytest.mark.slow  # a dozen training processes, a few seconds each
def test_contention_section_measures_solo_and_two_processes(tmp_path) -> None:
    """spade.bench's contention section starts each setting's training processes alone and two at a time and
    reports steps/s of each, with the thread count each one used."""
    from spade.perf.contention import contention_table, format_contention

    rows = contention_table([{"threads": None, "wait_policy": None}, {"threads": 1, "wait_policy": "PASSIVE"}],
                            size="small", image_size=32, batch_size=8, seconds=1.5)
    assert [r["setting"] for r in rows] == ["threads=torch default, OMP_WAIT_POLICY=unset",
                                            "threads=1, OMP_WAIT_POLICY=PASSIVE"]
    for r in rows:
        assert r["solo_steps_per_s"] > 0 and len(r["pair_steps_per_s"]) == 2 and min(r["pair_steps_per_s"]) > 0
        assert r["pair_vs_own_solo"] == pytest.approx(min(r["pair_steps_per_s"]) / r["solo_steps_per_s"])
    assert rows[1]["solo_threads"] == 1 and rows[1]["pair_threads"] == [1, 1]
    assert rows[0]["solo_vs_default"] == 1.0
    assert "| threads=1, OMP_WAIT_POLICY=PASSIVE | 1 / 1 / 1 |" in format_contention(rows, "small")
