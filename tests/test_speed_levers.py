"""The trainer's speed options (spade/training/speed.py) and the bench's training levers (spade/perf/training.py):
they compose, resolve on the machine, refuse bad values by name, and a tiny step under each one trains."""

from __future__ import annotations

from pathlib import Path

import hydra
import lightning as L
import pytest
import torch

from spade.perf.step_cost import matmul_gflops, step_gflop, top_operators
from spade.perf.training import LEVERS, Setup, applies, build_step, example_batch, student_with_margin
from spade.training.callbacks import ChannelsLast
from spade.training.speed import (Bf16Module, build_trainer, resolve_channels_last,
                                  resolve_precision, use_bf16_expert)
from spade.utils.config import compose_config
from spade.utils.errors import ConfigError


def _callbacks(trainer: L.Trainer) -> list[type]:
    return [type(c) for c in trainer.callbacks]


@pytest.mark.parametrize("overrides", [[], ["trainer.precision=auto"], ["trainer.channels_last=false"],
                                       ["trainer.precision=bf16-mixed"]])
def test_trainer_options_compose_and_instantiate(overrides: list[str], tmp_path: Path) -> None:
    cfg = compose_config("train", ["logger=none", f"paths.output_dir={tmp_path}", *overrides])
    trainer = hydra.utils.instantiate(cfg.trainer)
    assert isinstance(trainer, L.Trainer)
    assert (ChannelsLast in _callbacks(trainer)) == resolve_channels_last(cfg.trainer.channels_last, "cpu")
    expected = "bf16-mixed" if resolve_precision(cfg.trainer.precision, "cpu") == "bf16-mixed" else "32-true"
    assert trainer.precision == expected


def test_gpu_trainer_keeps_one_channels_last_callback() -> None:
    cfg = compose_config("train", ["logger=none", "trainer=gpu"])
    assert cfg.trainer.precision == "bf16-mixed" and cfg.trainer.channels_last == "auto"
    from spade.training.speed import speed_callbacks

    assert speed_callbacks(True, [ChannelsLast()]) == []


def test_auto_values_follow_the_detected_hardware(monkeypatch: pytest.MonkeyPatch) -> None:
    import spade.training.speed as speed

    monkeypatch.setattr(speed, "bf16_fast", lambda accelerator: True)
    assert resolve_precision("auto", "cpu") == "bf16-mixed"
    monkeypatch.setattr(speed, "bf16_fast", lambda accelerator: False)
    assert resolve_precision("auto", "cpu") == "32-true"
    assert resolve_precision("bf16-mixed", "cpu") == "bf16-mixed" and resolve_precision(32) == "32"
    assert resolve_channels_last("auto", "gpu") is True and resolve_channels_last(False, "gpu") is False


@pytest.mark.parametrize("kwargs, key", [({"precision": "fp7"}, "trainer.precision"),
                                         ({"channels_last": "maybe"}, "trainer.channels_last")])
def test_bad_values_name_the_option(kwargs: dict, key: str) -> None:
    with pytest.raises(ConfigError, match=key):
        build_trainer(accelerator="cpu", logger=False, **kwargs)


@pytest.mark.parametrize("approach, preset", [("BC", None), ("Cond-DBC", "tiny"), ("DBC", "tiny"), ("Expert", "tiny")])
def test_a_tiny_step_trains_under_every_lever(approach: str, preset: str | None) -> None:
    setup = Setup(approach, None if approach == "Expert" else "small", preset)
    batch = example_batch(2, 32)
    for lever in LEVERS.values():
        if not applies(setup, lever):
            continue
        step = build_step(setup, lever, batch)
        losses = [float(step()) for _ in range(2)]
        assert all(torch.isfinite(torch.tensor(losses))), (approach, lever.name, losses)


def test_flop_count_and_references_are_positive() -> None:
    step = build_step(Setup("BC", "small"), LEVERS["baseline"], example_batch(2, 32))
    assert step_gflop(step) > 0
    assert matmul_gflops(64, 0.01) > 0
    ops = top_operators(step, top=3)
    assert len(ops) == 3 and all(o["self_cpu_ms"] > 0 and 0 < o["share"] <= 1 for o in ops)


def test_bf16_expert_stays_bf16_and_passes_gradients() -> None:
    module = student_with_margin("small", "cond", "tiny")
    assert use_bf16_expert(module) and not use_bf16_expert(module)  # once
    module.to(torch.float32)  # the student's casts leave the frozen expert in bf16
    assert next(module.margin.expert.parameters()).dtype == torch.bfloat16
    assert isinstance(module.margin.expert, Bf16Module)
    batch = example_batch(2, 32)
    loss = module.losses(batch)["loss"]
    assert loss.dtype == torch.float32 and torch.isfinite(loss)
    loss.backward()
    assert all(p.grad is not None for p in module.net.parameters() if p.requires_grad)
    assert not use_bf16_expert(student_with_margin("small"))  # BC: no expert


def test_fit_with_every_option_on(tmp_path: Path) -> None:
    """Lightning's bf16-mixed on the CPU, channels_last and the bf16 expert (the bench's lever) together, through
    Trainer.fit."""
    module = student_with_margin("small", "cond", "tiny")
    batch = example_batch(2, 32)
    loader = torch.utils.data.DataLoader([dict(batch), dict(batch)], batch_size=None)
    use_bf16_expert(module)
    trainer = build_trainer(accelerator="cpu", precision="bf16-mixed", channels_last=True, max_steps=2,
                            logger=False, enable_checkpointing=False, enable_progress_bar=False,
                            enable_model_summary=False, limit_val_batches=0, num_sanity_val_steps=0,
                            default_root_dir=str(tmp_path))
    trainer.fit(module, train_dataloaders=loader)
    assert trainer.global_step == 2 and isinstance(module.margin.expert, Bf16Module)
    assert next(module.net.parameters()).dtype == torch.float32  # fp32 master weights
    assert torch.isfinite(trainer.callback_metrics["train/loss"])


def test_speed_page_is_written_from_the_results(tmp_path: Path) -> None:
    from spade.perf.speed_page import write_speed_page

    row = {"approach": "BC", "student": "medium", "expert_preset": None, "image_size": 64, "batch_size": 32,
           "gflop": 90.0, "step_ms": 1000.0, "steps_per_s": 1.0, "gflops": 90.0, "matmul_gflops": 200.0,
           "ratio_to_matmul": 0.45, "ratio_to_bc": 1.0}
    lever = {"setup": "BC", "expert_preset": None, "lever": "channels_last", "step_ms": 800.0, "steps_per_s": 1.25,
             "speedup": 1.25, "gflops": 112.5, "ratio_to_matmul": 0.56, "loss_finite": True}
    ops = [{"op": "aten::convolution_backward", "self_cpu_ms": 500.0, "share": 0.5, "calls": 10},
           {"op": "aten::native_batch_norm", "self_cpu_ms": 300.0, "share": 0.3, "calls": 8}]
    results = {"machine": {"cpu": "CPU", "cpu_count": 2, "torch": "2", "torch_threads": 1}, "training": [row],
               "training_speed": {"hardware": {"cpu_capability": "AVX512", "cpu_bf16": False}, "levers": [lever],
                                  "profiles": [{"setup": "BC", "lever": "baseline", "image_size": 64,
                                                "batch_size": 32, "operators": ops}],
                                  "lightning": [{"setting": "bare loop", "step_ms": 1000.0, "overhead_ms": 0.0,
                                                 "steps": 4}]}}
    text = write_speed_page(results, tmp_path / "speed.md", "python -m spade.bench", "abc", 60.0).read_text()
    assert "`python -m spade.bench`" in text and "`abc`" in text and "NOT reached" in text
    assert "| BC | - | channels_last | 800 | 1.25 | 1.25 |" in text and "aten::native_batch_norm" in text

    assert "[precision page](precision.md)" in text

    from spade.perf.speed_page import rerender

    (tmp_path / "speed.md").write_text("stale")
    assert rerender(tmp_path / "speed.json").read_text() == text  # the recorded figures, written again


# -- the evaluation's cost: one test pass and one closed-loop drive (spade/perf/evaluation_cost.py) ----------------
def _parts_add_up(result: dict) -> None:
    *parts, total = result["rows"]
    assert total["part"] == "total" and total["share"] == 1.0 and total["ms"] > 0
    assert all(r["ms"] > 0 and r["ms_each"] > 0 and 0 < r["share"] < 1 for r in parts)
    assert sum(r["ms"] for r in parts) == pytest.approx(total["ms"], rel=1e-6)
    assert sum(r["share"] for r in parts) == pytest.approx(1.0, rel=1e-6)


def test_a_test_pass_and_a_drive_say_where_their_time_goes() -> None:
    from spade.perf.evaluation_cost import one_drive_cost, one_test_pass_cost

    test = one_test_pass_cost("small", image_size=32, instances=3, batch_size=2)
    assert (test["student"], test["instances"], test["batch_size"]) == ("small", 3, 2)
    assert [r["part"] for r in test["rows"]][:6] == ["network (forward)", "search decoder", "metrics update (model)",
                                                    "baselines' and references' paths",
                                                    "baselines' and references' metrics", "metrics compute"]
    _parts_add_up(test)
    drive = one_drive_cost("small", scenarios=2, image_size=32)
    assert drive["scenarios"] == 2 and drive["queries"] >= 2 and drive["control_steps"] > 0
    assert [r["part"] for r in drive["rows"]][:3] == ["network (forward)", "search decoder",
                                                      "windows (resample, rotate, encode)"]
    assert all(r["ms_per_query"] > 0 for r in drive["rows"][:3]) and drive["query_ms"] > 0
    _parts_add_up(drive)
    with pytest.raises(ValueError, match="instances >= 1"):
        one_test_pass_cost("small", 32, 0)


def test_the_bench_training_section_times_the_evaluation_and_zero_skips_it() -> None:
    from spade.perf.bench import _training

    t = {"student": "small", "image_sizes": [32], "batch_size": 2, "cond_presets": [], "uncond_preset": None,
         "runs": 1, "warmup": 0, "batched_terms": False, "matmul_size": 32, "matmul_seconds": 0.001, "levers": [],
         "profile_levers": [], "lightning_steps": 0, "lever_image_size": 32, "evaluation_instances": 2,
         "drive_scenarios": 1}
    _, speed = _training(t)
    assert speed["evaluation"]["test_pass"]["instances"] == 2 and speed["evaluation"]["drive"]["scenarios"] == 1
    _, speed = _training({**t, "evaluation_instances": 0, "drive_scenarios": 0})
    assert "evaluation" not in speed


def test_evaluation_cost_settings_are_checked_and_small_in_quick_mode(tmp_path: Path) -> None:
    from spade.config.bench_checks import validate_bench_config
    from spade.perf.bench import SECTIONS  # registers the quick_or resolver

    quick, full = compose_config("bench", ["quick=true"]), compose_config("bench", [])
    assert quick.training.evaluation_instances < full.training.evaluation_instances
    assert quick.training.drive_scenarios < full.training.drive_scenarios
    for override, expected in (("training.evaluation_instances=-1", "training.evaluation_instances=-1 is out of range"),
                               ("training.drive_scenarios=two", "training.drive_scenarios='two' is not an integer")):
        with pytest.raises(ConfigError, match=expected) as err:
            validate_bench_config(compose_config("bench", ["quick=true", f"out_json={tmp_path / 'b.json'}", override]),
                                  SECTIONS)
        assert "\n" not in str(err.value) and "0: no" in str(err.value)


def _evaluation_results() -> dict:
    def rows(parts: dict[str, float], per: int, queries: int = 0) -> list[dict]:
        total = sum(parts.values())
        out = [{"part": k, "ms": v, "ms_each": v / per, "share": v / total} for k, v in [*parts.items(),
                                                                                         ("total", total)]]
        for r in out[:3] if queries else []:
            r["ms_per_query"] = r["ms"] / queries
        return out

    test = {"student": "medium", "image_size": 64, "instances": 32, "batch_size": 32,
            "rows": rows({"network (forward)": 1266.0, "search decoder": 124.0, "metrics update (model)": 306.0,
                          "baselines' and references' paths": 1866.0, "baselines' and references' metrics": 300.0,
                          "metrics compute": 19.0}, 32)}
    drive = {"student": "medium", "image_size": 64, "scenarios": 4, "queries": 20, "control_steps": 376,
             "successes": 4, "query_ms": 41.7,
             "rows": rows({"network (forward)": 680.0, "search decoder": 76.0, "windows (resample, rotate, encode)":
                           77.0, "follower, collision checks, loop": 72.0, "metrics": 14.0}, 4, 20)}
    return {"machine": {"cpu": "CPU", "cpu_count": 2, "torch": "2", "torch_threads": 1},
            "training_speed": {"hardware": {}, "evaluation": {"test_pass": test, "drive": drive}}}


def test_the_speed_page_and_the_report_show_where_evaluation_time_goes() -> None:
    from spade.perf.bench_report import format_report
    from spade.perf.speed_page import speed_page

    results = _evaluation_results()
    page = speed_page(results, "python -m spade.bench", "abc", 60.0, date="today")
    section = page.split("## One test pass and one closed-loop drive: where the time goes\n\n", 1)[1]
    assert "| part | ms | ms / instance | share |" in section and "| search decoder | 124 | 3.88 | 3% |" in section
    assert "| part | ms | ms / scenario | ms / query | share |" in section
    assert "| network (forward) | 680 | 170 | 34 | 74% |" in section and "| metrics | 14 | 3.5 | - | 2% |" in section
    assert "20 planning queries, 376 control steps, 4 of 4 reached the goal" in section
    assert all(line.count("|") <= 7 for line in section.splitlines() if line.startswith("|"))  # <= 6 columns
    assert "### One test pass and one closed-loop drive: where the time goes" in format_report(results)
    del results["training_speed"]["evaluation"]["drive"]
    assert "ms / scenario" not in speed_page(results, "python -m spade.bench", "abc", 60.0, date="today")
