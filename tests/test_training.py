"""Training behaviour: losses fall, the expert stays frozen, resume, reliability and the smoke pipeline."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import hydra
import numpy as np
import pytest
import torch

from spade.experiments.run import train
from spade.training.expert_module import ExpertModule
from spade.training.student_module import ExpertMismatchError, StudentModule
from fault_injection import env_with_tests, kill_at
from training_helpers import compose_row
from spade.tracking.predictors import TOP_LEVEL_FILTER

REPO = Path(__file__).resolve().parents[1]


def _data(spade_home: Path, row: str = "t1_small_bc_L"):
    cfg = compose_row(row, spade_home)
    dm = hydra.utils.instantiate(cfg.data, augment=False)
    dm.prepare_data()
    dm.setup("fit")
    return dm


def _falls(losses: list[float]) -> bool:
    k = max(3, len(losses) // 5)
    return sum(losses[-k:]) / k < 0.8 * sum(losses[:k]) / k


def _fit_steps(module, loss_fn, batches, steps: int, lr: float) -> list[float]:
    opt = torch.optim.Adam([p for p in module.parameters() if p.requires_grad], lr=lr)
    out = []
    for i in range(steps):
        loss = loss_fn(batches[i % len(batches)])
        opt.zero_grad()
        loss.backward()
        opt.step()
        if hasattr(module, "ema"):
            module.ema.update_parameters(module.net)
        out.append(loss.item())
    return out


# Slow: 140 training steps on the tiny data, minutes on 2 cores. Fast: test_models' student_learns_one_instance,
# test_learning_core's briefly_trained_conditional_expert_uses_its_state, one_margin_step_moves_the_student_...
@pytest.mark.slow
def test_bc_expert_and_cond_dbc_losses_fall(spade_home: Path, tiny_checkpoints: dict) -> None:
    torch.manual_seed(0)
    batches = list(_data(spade_home).train_dataloader())[:4]
    student = StudentModule(size="small")
    assert _falls(_fit_steps(student, lambda b: student.losses(b)["loss_bc"], batches, 40, 3e-3))
    expert = ExpertModule(conditional=True, preset="tiny")
    assert _falls(_fit_steps(expert, lambda b: expert.denoising_loss(expert.net, b), batches, 60, 3e-3))
    guided = StudentModule(size="small", margin={"expert_ckpt": tiny_checkpoints["cond"], "lambda_dm": 1.0})
    guided.load_margin((64, 64))
    assert _falls(_fit_steps(guided, lambda b: guided.losses(b)["loss"], batches, 40, 3e-3))


def test_a_margin_step_changes_the_student_never_the_expert(spade_home: Path, tiny_checkpoints: dict) -> None:
    batch = next(iter(_data(spade_home).train_dataloader()))
    # The expert judges the path the student commits to (straight-through): with the student drawing no path at all
    # (bias -4), an x0 expert rates it below the demonstration, so the margin acts. (It rates a soft map above the
    # demonstration: docs/results/guidance.md, so the paper's soft input would give no margin to test here.)
    student = StudentModule(size="small", margin={"expert_ckpt": tiny_checkpoints["cond"], "lambda_dm": 5.0,
                                                  "agent_input": "straight_through"})
    student.load_margin((64, 64))
    with torch.no_grad():
        student.net.head.bias.fill_(-4.0)
    expert = student.margin.expert
    before = {k: v.clone() for k, v in expert.state_dict().items()}
    opt = torch.optim.SGD([p for p in student.parameters() if p.requires_grad], lr=0.1)
    parts = student.losses(batch)
    parts["loss_dm"].backward()
    grads = [p.grad for p in student.net.parameters() if p.grad is not None]
    assert grads and sum(g.abs().sum() for g in grads) > 0
    opt.step()
    assert all(torch.equal(before[k], v) for k, v in expert.state_dict().items())
    assert all(p.grad is None for p in expert.parameters())
    assert not any(k.startswith("_margin") or "expert" in k for k in student.state_dict())


def test_margin_is_zero_when_the_student_outputs_the_demonstration(spade_home: Path, tiny_checkpoints: dict) -> None:
    batch = next(iter(_data(spade_home).train_dataloader()))
    student = StudentModule(size="small", margin={"expert_ckpt": tiny_checkpoints["cond"]})
    student.load_margin((64, 64))
    loss, active = student.margin(batch["path"], batch["path"], batch["state"], torch.Generator().manual_seed(0))
    assert loss.item() == 0.0 and active.item() == 0.0


def test_same_seed_gives_identical_metrics(spade_home: Path) -> None:
    runs = []
    for _ in range(2):
        cfg = compose_row("t1_small_bc_L", spade_home, "logger=none", "trainer.max_steps=3", "trainer.max_epochs=1",
                          "callbacks=none", "+trainer.limit_val_batches=1", "+trainer.limit_test_batches=2",
                          "data.eval_batch_size=16")
        metrics, _ = train(cfg)
        runs.append({k: v for k, v in metrics.items() if k.startswith("test/")})
    assert runs[0]
    np.testing.assert_equal(runs[0], runs[1])  # NaN-aware: a 3-step student may extract no path (APE NaN)


def test_nan_loss_stops_with_the_step(spade_home: Path) -> None:
    batch = next(iter(_data(spade_home).train_dataloader()))
    batch["state"][0, 0, 0, 0] = float("nan")
    student = StudentModule(size="small")
    with pytest.raises(FloatingPointError, match="global step 0"):
        student.training_step(batch, 0)


def test_a_non_finite_loss_seen_late_still_names_its_step() -> None:
    """On an accelerator the loss is looked at every few steps (one host sync), not every step: the first
    non-finite step is recorded on the device and named when the look comes."""

    class Probe(StudentModule):
        step = 0

        @property
        def global_step(self) -> int:
            return self.step

        def finite_check_every(self, device: torch.device) -> int:
            return 4

    probe = Probe(size="small")
    losses = [1.0, 0.5, float("nan"), 0.7, 0.6, 0.5, 0.4, 0.3]
    with pytest.raises(FloatingPointError, match=r"global step 2 .*\(seen at step 3"):
        for step, value in enumerate(losses):
            probe.step = step
            probe.check_finite(torch.tensor(value), {"loss_bc": torch.tensor(value)})
    assert probe.step == 3  # stopped at the first look after the bad step
    fine = Probe(size="small")
    for step, value in enumerate(losses[:2] + losses[3:]):
        fine.step = step
        fine.check_finite(torch.tensor(value), {"loss_bc": torch.tensor(value)})


def test_bc_pos_weight_weighs_path_pixels() -> None:
    logits = torch.tensor([[[[2.0, -1.0], [0.5, -3.0]]]])
    target = torch.tensor([[[[1.0, 0.0], [0.0, 1.0]]]])
    p = torch.sigmoid(logits)
    # Hand-computed: -(w * y log p + (1 - y) log(1 - p)), averaged over the 4 pixels.
    expected = -(4 * target * p.log() + (1 - target) * (1 - p).log()).mean()
    assert torch.allclose(StudentModule(size="small", bc_pos_weight=4).bc_loss(logits, target), expected)
    plain = -(target * p.log() + (1 - target) * (1 - p).log()).mean()
    assert torch.allclose(StudentModule(size="small").bc_loss(logits, target), plain)
    with pytest.raises(ValueError, match="bc_pos_weight"):
        StudentModule(size="small", bc_pos_weight=0)


def test_bad_inputs_fail_before_training(spade_home: Path, tiny_checkpoints: dict, tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="does not exist"):
        StudentModule(size="small", margin={"expert_ckpt": str(tmp_path / "missing.ckpt")})
    with pytest.raises(ValueError, match="small"):
        StudentModule(size="huge")
    with pytest.raises(ValueError, match="lambda"):
        StudentModule(size="small", margin={"expert_ckpt": tiny_checkpoints["cond"], "lambda_dm": -1.0})
    guided = StudentModule(size="small", margin={"expert_ckpt": tiny_checkpoints["cond"]})
    with pytest.raises(ExpertMismatchError, match="64 x 64"):
        guided.load_margin((32, 32))
    dbc = StudentModule(size="small", margin={"expert_ckpt": tiny_checkpoints["cond"], "expert": "unconditional"})
    with pytest.raises(ExpertMismatchError, match="conditional expert, but DBC"):
        dbc.load_margin((64, 64))
    with pytest.raises(ValueError, match=r"expert='film' is not one of"):
        StudentModule(size="small", margin={"expert_ckpt": tiny_checkpoints["cond"], "expert": "film"})
    expert = ExpertModule.load_from_checkpoint(tiny_checkpoints["uncond"], map_location="cpu")
    with pytest.raises(ExpertMismatchError, match="channels"):
        expert.check_compatible(in_channels=2, image_size=None, source="x")
    with pytest.raises(ValueError, match="init_ckpt"):
        StudentModule(size="small", init_ckpt=tiny_checkpoints["student"])  # a medium student's weights


def _run(args: list[str], home: Path, **kw) -> subprocess.Popen:
    env = env_with_tests({**os.environ, "SPADE_HOME": str(home), "PYTHONUNBUFFERED": "1"})
    return subprocess.Popen([sys.executable, "-m", "spade.train", *args], cwd=REPO, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, **kw)


@pytest.mark.slow  # a spade.train process
def test_smoke_experiment_logs_a_run_with_test_metrics(tmp_path: Path) -> None:
    proc = _run(["+experiment=smoke", "trainer.enable_progress_bar=false"], tmp_path)
    out, _ = proc.communicate(timeout=600)
    assert proc.returncode == 0, out[-3000:]
    assert "mlflow ui --backend-store-uri" in out
    from mlflow import MlflowClient

    client = MlflowClient(tracking_uri=f"sqlite:///{tmp_path}/logs/mlflow.db")
    exp = client.get_experiment_by_name("smoke")
    runs = client.search_runs([exp.experiment_id], filter_string=TOP_LEVEL_FILTER)
    assert len(runs) == 1 and runs[0].info.run_name == "smoke"
    run = runs[0]
    assert {"test/ape_cm", "test/hd19", "model/params"} <= set(run.data.metrics)
    assert run.data.tags["approach"] == "Cond-DBC" and "fid_extractor" in run.data.tags
    artifacts = {a.path for a in client.list_artifacts(run.info.run_id)}
    assert {"checkpoints", "config", "predictions"} <= artifacts
    assert client.search_model_versions("name LIKE 'spade-cond_expert-L-tiny-%'")


@pytest.mark.slow  # two spade.train processes; resume in-process: test_training_runs's resume_continues_the_run test
def test_killed_run_resumes_into_the_same_mlflow_run(tmp_path: Path) -> None:
    run_dir = tmp_path / "run"
    args = ["+experiment=t1_small_bc_L", "trainer.max_epochs=3", "+trainer.limit_train_batches=4",
            "trainer.enable_progress_bar=false", f"hydra.run.dir={run_dir}", "test=false"]
    # kill -9 by the run itself when batch 2 of epoch 1 starts: after epoch 0's checkpoint, in the middle of epoch 1
    proc = _run([*args, *kill_at(epoch=1, batch=2)], tmp_path, start_new_session=True)
    out, _ = proc.communicate(timeout=600)
    assert proc.returncode == -signal.SIGKILL, out[-3000:]
    last = run_dir / "checkpoints" / "last.ckpt"
    assert last.exists(), out[-3000:]
    resumed = run_dir / "resume.ckpt"
    resumed.write_bytes(last.read_bytes())
    proc = _run([*args, f"ckpt_path={resumed}"], tmp_path)
    out, _ = proc.communicate(timeout=600)
    assert proc.returncode == 0, out[-3000:]
    from mlflow import MlflowClient

    client = MlflowClient(tracking_uri=f"sqlite:///{tmp_path}/logs/mlflow.db")
    runs = client.search_runs([client.get_experiment_by_name("table1").experiment_id], filter_string=TOP_LEVEL_FILTER)
    assert len(runs) == 1
    epochs = [m.value for m in client.get_metric_history(runs[0].info.run_id, "epoch")]
    assert max(epochs) == 2
    # Continued, not restarted: the steps before the checkpoint were logged once (by the killed process only).
    ckpt_step = torch.load(resumed, map_location="cpu", weights_only=False)["global_step"]
    steps = [m.step for m in client.get_metric_history(runs[0].info.run_id, "train/loss_bc")]
    assert ckpt_step > 0 and all(steps.count(s) == 1 for s in steps if s < ckpt_step)


def test_evaluate_entry_point_tests_a_checkpoint(spade_home: Path, tiny_checkpoints: dict) -> None:
    from spade.evaluate import evaluate, load_module
    from spade.utils.config import compose_config

    cfg = compose_config("evaluate", [f"ckpt_path={tiny_checkpoints['student']}", "logger=none",
                                      "trainer.enable_progress_bar=false", f"paths.output_dir={spade_home}/eval"])
    metrics = evaluate(cfg)
    assert {"test/ape_cm", "test/hd19", "test/failure_rate"} <= set(metrics)
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_module(spade_home / "nope.ckpt")


def test_evaluate_samples_an_expert_as_expert_sampling_says_and_refuses_it_for_a_student(
        spade_home: Path, tiny_checkpoints: dict) -> None:
    """expert_sampling replaces an expert checkpoint's sampler, steps and K at test (a lever measured without
    retraining); on a student, or with a bad value, it is a one-line refusal before any work."""
    from spade.config.evaluate_checks import validate_evaluate_config
    from spade.evaluate import load_module
    from spade.experiments.evaluation import evaluate
    from spade.utils.config import compose_config
    from spade.utils.errors import ConfigError

    expert = tiny_checkpoints["cond"]
    own = load_module(expert)
    loaded = load_module(expert, sampler="ddpm", num_inference_steps=3, test_samples=2)
    assert (loaded.hparams.sampler, loaded.hparams.num_inference_steps, loaded.hparams.test_samples) == ("ddpm", 3, 2)
    assert own.hparams.sampler == "ddim" and own.hparams.num_inference_steps != 3

    base = ["logger=none", "trainer.enable_progress_bar=false", f"paths.output_dir={spade_home}/eval_sampling"]
    with pytest.raises(ConfigError, match="pass an expert checkpoint"):
        validate_evaluate_config(compose_config("evaluate", [f"ckpt_path={tiny_checkpoints['student']}",
                                                             "expert_sampling.sampler=ddpm", *base]))
    for bad, match in (("expert_sampling.sampler=euler", "is not a sampler; valid: ddim, ddpm"),
                       ("expert_sampling.test_samples=1", "expert_sampling.test_samples=1"),
                       ("+expert_sampling.eta=0.5", "expert_sampling.eta is not a sampling setting"),
                       ("expert_sampling.guidance_scale=2", "needs an expert trained with model.cond_dropout > 0")):
        with pytest.raises(ConfigError, match=match):
            validate_evaluate_config(compose_config("evaluate", [f"ckpt_path={expert}", bad, *base]))
    from mlflow import MlflowClient

    uri = f"sqlite:///{spade_home}/sampling.db"
    metrics = evaluate(compose_config("evaluate", [f"ckpt_path={expert}", "expert_sampling.sampler=ddpm",
                                                   "expert_sampling.num_inference_steps=3",
                                                   "expert_sampling.test_samples=2", "run_name=ddpm3",
                                                   *base[1:], f"paths.mlflow_tracking_uri={uri}"]))
    assert "test/planner/ape_cm" in metrics and metrics["test/seconds_per_sample"] > 0
    client = MlflowClient(tracking_uri=uri)  # the run records the sampling it was tested with
    (run,) = client.search_runs([e.experiment_id for e in client.search_experiments()],
                                "attributes.run_name = 'ddpm3'")
    assert {k: run.data.params[f"cfg/model/{k}"] for k in ("sampler", "num_inference_steps", "test_samples")} == {
        "sampler": "ddpm", "num_inference_steps": "3", "test_samples": "2"}
    # and the size of the network it tested, as a training run records it (the teacher pages' parameters column)
    assert run.data.metrics["model/params"] == sum(p.numel() for p in own.net.parameters() if p.requires_grad)
