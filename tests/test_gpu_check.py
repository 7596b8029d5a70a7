"""The GPU readiness script (``python -m spade.gpu_check``), exercised on the CPU at tiny sizes.

On a machine with an NVIDIA GPU the same code runs at the paper's scale; here the sections must run, measure and
report, and ``device=cuda`` without a GPU must stop with one clear line.
"""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from spade.perf.gpu import DeviceUnavailableError, format_gpu_report, gpu_check

REPO = Path(__file__).resolve().parents[1]
TINY = {"device": "cpu", "precision": "fp32", "sections": ["steps", "sampling"], "seed": 0, "image_size": 32,
        "batch_size": 2, "timed_steps": 1, "cond_preset": "tiny", "uncond_preset": "tiny", "uncond_batch_size": 2,
        "student": "small", "student_uncond_preset": "tiny", "peak_tflops": 1.0, "ddim_steps": 2, "train_steps": 2,
        "work_dir": None,
        "pipeline": {"experiment": "t1_medium_conddbc_L", "overrides": ["scale=tiny", "trainer=cpu"], "timeout_s": 600}}
TINY_ARGS = ["device=cpu", "precision=fp32", "image_size=32", "student=small", "cond_preset=tiny", "uncond_preset=tiny",
             "student_uncond_preset=tiny", "batch_size=2", "uncond_batch_size=2", "timed_steps=1", "train_steps=2", "ddim_steps=2"]


def test_steps_and_sampling_are_measured_on_cpu() -> None:
    results = gpu_check(TINY)
    experts, uncond, bc, dbc, guided = results["steps"]
    assert (experts["expert"], uncond["expert"], bc["approach"], dbc["approach"], guided["approach"]) == (
        "cond", "uncond", "BC", "DBC", "Cond-DBC")
    for row in results["steps"]:
        assert row["step_ms"] > 0 and math.isfinite(row["loss_first"]) and math.isfinite(row["loss_last"])
        # FLOPs counted, rate and utilisation derived from them; no GPU to be busy on a CPU
        assert row["gflop_per_step"] > 0 and row["steps_per_s"] == pytest.approx(1000 / row["step_ms"], rel=0.01)
        assert row["achieved_tflops"] == pytest.approx(row["gflop_per_step"] / 1000 * row["steps_per_s"], rel=0.05)
        assert row["mfu"] == pytest.approx(row["achieved_tflops"], rel=0.01) and row["device_busy_share"] is None
    assert guided["gflop_per_step"] > bc["gflop_per_step"]  # the margin's expert passes
    assert experts["batch_size"] == 2 and experts["params_m"] > 0
    assert guided["ratio_to_bc"] == pytest.approx(guided["step_ms"] / bc["step_ms"], rel=0.01)
    assert results["sampling"]["ms_per_sample"] > 0 and results["sampling"]["ddim_steps"] == 2
    report = format_gpu_report(results)
    assert "Cond-DBC" in report and "DDIM-2" in report


def test_bad_settings_are_named() -> None:
    with pytest.raises(ValueError, match="precision must be bf16 or fp32"):
        gpu_check({**TINY, "precision": "fp8"})
    with pytest.raises(ValueError, match="unknown gpu_check sections"):
        gpu_check({**TINY, "sections": ["steps", "warp"]})
    with pytest.raises(ValueError, match="device must be"):
        gpu_check({**TINY, "device": "tpu"})


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has a GPU")
def test_cuda_without_a_gpu_stops_with_one_line(tmp_path: Path) -> None:
    with pytest.raises(DeviceUnavailableError, match="no CUDA GPU"):
        gpu_check({**TINY, "device": "cuda"})
    env = {**os.environ, "SPADE_HOME": str(tmp_path)}
    proc = subprocess.run([sys.executable, "-m", "spade.gpu_check", "sections=[steps]"], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert "no CUDA GPU" in proc.stderr and "Traceback" not in proc.stderr


@pytest.mark.slow
def test_the_whole_check_runs_end_to_end_on_cpu(tmp_path: Path) -> None:
    """Every section, the pipeline's expert and Cond-DBC student included, at scale=tiny on the CPU."""
    env = {**os.environ, "SPADE_HOME": str(tmp_path), "OMP_NUM_THREADS": "1"}
    env.pop("MLFLOW_TRACKING_URI", None)
    proc = subprocess.run([sys.executable, "-m", "spade.gpu_check", *TINY_ARGS,
                           'pipeline.overrides=["scale=tiny","trainer=cpu"]'], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    results = json.loads((tmp_path / "logs" / "gpu_check" / "gpu_check.json").read_text())
    pipeline = results["pipeline"]
    assert pipeline["exit_code"] == 0 and not pipeline["timed_out"]
    runs = {r["run"]: r for r in pipeline["runs"]}
    assert set(runs) == {"cond_expert_L", "t1_medium_conddbc_L"}
    assert all(r["status"] == "FINISHED" and math.isfinite(r["planner/ape_cm"]) for r in runs.values())
    assert "| t1_medium_conddbc_L | FINISHED |" in proc.stdout
