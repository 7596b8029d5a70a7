"""The learning core: baselines, the failure-aware score, Hd19 in metres, EMA warm-up, the margin gradient,
the total loss, and a conditional expert that uses its state."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from spade.data.rasterize import robot_instance
from spade.maps.frame import RobotFrame
from spade.metrics.ape import APE
from spade.metrics.hausdorff import HausdorffCount
from spade.metrics.baselines import BASELINES, baseline_images, baseline_polylines, heading_template, shortest_path
from spade.training.expert_module import WarmupEMA, ema_decay_at
from spade.training.margin import DiffusionMargin, MarginConfig


def _batch(turn: float = 1.0, wall: bool = False) -> dict:
    """One robot-frame L instance as a batch of one (0.1 m/px)."""
    t = np.linspace(0, 1, 60)
    leg = np.stack([np.full(30, 60.0), np.linspace(80, 60, 30)], axis=1)
    arc = np.stack([60 + turn * (8 - 8 * np.cos(t * np.pi / 2)), 60 - 8 * np.sin(t * np.pi / 2)], axis=1)
    tail = np.stack([60 + turn * np.linspace(8, 16, 10), np.full(10, 52.0)], axis=1)
    grid = np.ones((140, 140), np.uint8)
    if wall:
        grid[55:58, 50:75] = 2  # a wall across the straight line from start to goal
    inst = robot_instance(grid, np.concatenate([leg, arc, tail]), RobotFrame.for_size(64), 2, 1.0, 32)
    assert inst is not None
    state = np.stack([inst.occupancy * 0.5, inst.start, inst.goal]).astype(np.float32)
    return {"state": torch.from_numpy(state)[None], "path": torch.from_numpy(inst.path[None, None].astype(np.float32)),
            "waypoints": torch.from_numpy(inst.waypoints)[None], "resolution": torch.tensor([0.1])}


def test_baselines_by_hand() -> None:
    start, goal = np.array([32.0, 48.0]), np.array([40.0, 30.0])
    np.testing.assert_allclose(heading_template(start, goal), [[32, 48], [32, 30], [40, 30]])
    batch = _batch()
    polys = baseline_polylines(batch["state"][0].numpy(), 0.1)
    assert set(polys) == set(BASELINES)
    np.testing.assert_allclose(polys["straight"][0], [32, 48], atol=0.5)
    # With nothing in the way, the costmap's shortest path is about as long as the straight line (an 8-connected
    # grid path, smoothed, is a little longer) and ends on the goal.
    length = lambda p: float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())  # noqa: E731
    assert length(polys["straight"]) <= length(polys["shortest"]) < 1.1 * length(polys["straight"])
    np.testing.assert_allclose(polys["shortest"][-1], polys["straight"][-1], atol=0.5)
    # The heading template is the right answer for an L with a sharp corner: far better than the straight line.
    ape = {}
    images = baseline_images(batch["state"], batch["resolution"])
    for name, image in images.items():
        metric = APE()
        metric.update(image, batch["state"], batch["waypoints"], batch["resolution"])
        ape[name] = float(metric.compute()["ape_cm"])
    assert ape["heading"] < 0.6 * ape["straight"], ape


def test_shortest_path_goes_around_a_wall_and_fails_when_enclosed() -> None:
    occ = np.ones((64, 64), np.uint8)
    occ[30, 10:54] = 2
    path = shortest_path(occ, np.array([32.0, 48.0]), np.array([32.0, 12.0]), 0.1)
    assert path is not None and (path[:, 0].min() < 10 or path[:, 0].max() > 53)  # around an end of the wall
    cells = np.rint(path).astype(int)
    assert (occ[cells[:, 1], cells[:, 0]] == 1).all()
    occ[:, 20] = 2
    occ[:, 44] = 2
    occ[40, :] = 2
    assert shortest_path(occ, np.array([32.0, 48.0]), np.array([32.0, 12.0]), 0.1) is None


def test_score_counts_failures_as_the_straight_line() -> None:
    batch = _batch()
    images = baseline_images(batch["state"], batch["resolution"])
    straight = APE()
    straight.update(images["straight"], batch["state"], batch["waypoints"], batch["resolution"])
    empty = APE()
    empty.update(torch.zeros_like(batch["path"]), batch["state"], batch["waypoints"], batch["resolution"])
    s, e = straight.compute(), empty.compute()
    assert int(e["failures"]) == 1 and torch.isnan(e["ape_cm"])
    assert float(e["score_cm"]) == pytest.approx(float(s["ape_cm"]), rel=0.05)
    perfect = APE()
    perfect.update(batch["path"], batch["state"], batch["waypoints"], batch["resolution"])
    assert float(perfect.compute()["score_cm"]) < 5


def test_hd19_in_metres_is_19_px_at_the_papers_resolution() -> None:
    pred = torch.zeros(2, 1, 64, 64)
    truth = torch.zeros(2, 1, 64, 64)
    truth[:, 0, 10, 10:20] = 1
    pred[:, 0, 10, 10:20] = 1
    pred[:, 0, 10 + 12, 15] = 1  # a stray pixel 12 px away
    m = HausdorffCount(threshold_m=0.95, name="hd19")
    m.update(pred, truth, torch.tensor([0.1, 0.05]))  # 9.5 px vs 19 px
    out = m.compute()
    assert int(out["hd19"]) == 1  # counted at 0.1 m/px (1.2 m > 0.95 m), not at 0.05 m/px (0.6 m)
    with pytest.raises(ValueError, match="resolution"):
        HausdorffCount(threshold_m=0.95).update(pred, truth)


def test_ema_warmup_follows_diffusers_schedule_and_tracks_the_weights() -> None:
    assert ema_decay_at(0, 0.999) == pytest.approx(0.1)
    assert ema_decay_at(90, 0.999) == pytest.approx(91 / 100)
    assert ema_decay_at(10**6, 0.999) == 0.999
    net = torch.nn.Linear(3, 1)
    ema = torch.optim.swa_utils.AveragedModel(net, multi_avg_fn=WarmupEMA(0.99), use_buffers=True)
    torch.nn.init.constant_(net.weight, 5.0)
    ema.update_parameters(net)  # first update copies
    torch.nn.init.constant_(net.weight, 1.0)
    for _ in range(60):
        ema.update_parameters(net)
    # With the warm-up, the average has almost forgotten the initial 5.0; a fixed 0.99 decay would still hold
    # 0.99**60 = 55 % of it (about 3.2).
    assert float(ema.module.weight.detach().mean()) < 1.05


class _AnalyticExpert(torch.nn.Module):
    """eps(x_t, t) of a data distribution concentrated on one image x* (the demonstration): the exact optimal
    denoiser, so the margin's gradient must pull the student's output towards x*."""

    def __init__(self, target: torch.Tensor, alphas_cumprod: torch.Tensor) -> None:
        super().__init__()
        self.register_buffer("target", target)
        self.register_buffer("acp", alphas_cumprod)

    def forward(self, x_t: torch.Tensor, t: torch.Tensor, cond: torch.Tensor | None = None) -> torch.Tensor:
        a = self.acp[t].view(-1, 1, 1, 1)
        return (x_t - a.sqrt() * self.target) / (1 - a).sqrt()


def _analytic_margin(target01: torch.Tensor, weight: float = 1.0) -> DiffusionMargin:
    from spade.models.diffusion import NoiseSchedule, to_model_range

    schedule = NoiseSchedule(num_train_timesteps=100, beta_schedule="squaredcos_cap_v2")
    expert = _AnalyticExpert(to_model_range(target01), schedule.alphas_cumprod)
    return DiffusionMargin(expert, schedule.add_noise, 100, True, MarginConfig(lambda_dm=weight, t_min=5))


def test_one_margin_step_moves_the_student_towards_the_demonstration() -> None:
    torch.manual_seed(0)
    target = _batch()["path"]
    margin = _analytic_margin(target)
    logits = torch.zeros_like(target, requires_grad=True)  # a student that outputs 0.5 everywhere
    state = torch.zeros(1, 3, 64, 64)
    loss, active = margin(torch.sigmoid(logits), target, state, torch.Generator().manual_seed(1))
    assert loss > 0 and active == 1
    loss.backward()
    step = -logits.grad
    # Descending L_DM raises the logits on the path and lowers them off it.
    assert step[target > 0.5].mean() > 0 > step[target < 0.5].mean()


def test_total_loss_is_bc_plus_lambda_times_margin() -> None:
    from spade.training.student_module import StudentModule

    torch.manual_seed(0)
    batch = _batch()
    batch["target"] = batch["path"]
    student = StudentModule(size="small")
    lam = 2.5
    student.margin_cfg = MarginConfig(lambda_dm=lam)
    student._margin.append(_analytic_margin(batch["path"], lam))
    torch.manual_seed(3)
    parts = student.losses(batch)
    assert float(parts["loss"]) == pytest.approx(float(parts["loss_bc"] + lam * parts["loss_dm"]), rel=1e-6)


def _train_steps(expert, opt, state: torch.Tensor, path: torch.Tensor, n: int, steps: int) -> list[float]:
    losses = []
    for _ in range(steps):
        idx = torch.randint(0, n, (16,))
        loss = expert.denoising_loss(expert.net, {"state": state[idx], "path": path[idx]})
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
    return losses


def test_briefly_trained_conditional_expert_uses_its_state() -> None:
    """A tiny FiLM expert trained for 150 steps on data where the path is the column under the goal
    denoises better with the right state than with another instance's state."""
    from spade.training.expert_module import ExpertModule

    torch.manual_seed(0)
    size, n = 16, 64
    cols = torch.randint(2, size - 2, (n,))
    state = torch.zeros(n, 3, size, size)
    state[:, 0] = 0.5
    path = torch.zeros(n, 1, size, size)
    for i, c in enumerate(cols):
        state[i, 1, size - 2, c] = 1.0  # start at the bottom of the column
        state[i, 2, 1, c] = 1.0  # goal at its top
        path[i, 0, 1:size - 1, c] = 1.0
    expert = ExpertModule(conditional=True, preset="tiny", num_train_timesteps=100, ema_decay=0.9)
    opt = torch.optim.AdamW(expert.net.parameters(), lr=5e-3)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # tiny convolutions: one thread is fastest, and immune to a busy machine's oversubscription
    try:
        losses = _train_steps(expert, opt, state, path, n, 150)
    finally:
        torch.set_num_threads(threads)
    assert sum(losses[-10:]) < 0.5 * sum(losses[:10])
    gen = lambda: torch.Generator().manual_seed(7)  # noqa: E731  same noise and timesteps for both
    expert.net.eval()
    with torch.no_grad():
        right = expert.denoising_loss(expert.net, {"state": state, "path": path}, gen())
        wrong = expert.denoising_loss(expert.net, {"state": state[torch.roll(torch.arange(n), 1)], "path": path}, gen())
    assert float(right) < 0.8 * float(wrong), (float(right), float(wrong))


@pytest.mark.slow
def test_trained_student_beats_untrained_and_the_straight_line(spade_home) -> None:
    """A quickstart-like BC student (small, pos_weight 4, 3 px target), trained briefly on robot-frame L instances,
    beats the untrained student and the straight line on the held-out map (APE with failures scored as the
    straight line, i.e. ``score_cm``)."""
    from spade.experiments.run import train
    from training_helpers import compose_row

    cfg = compose_row("t1_small_bc_L", spade_home, "logger=none", "scale.train_instances=800", "trainer.max_epochs=8",
                      "model.bc_pos_weight=4", "recipe.student_lr=3e-3", "recipe.target_width_px=3",
                      "test_untrained=true", "paths.data_dir=" + str(spade_home / "data_slow"))
    metrics, _ = train(cfg)
    assert metrics["test/score_cm"] < 0.5 * metrics["untrained/score_cm"], metrics
    assert metrics["test/score_cm"] < metrics["test/baseline/straight/ape_cm"], metrics
    assert metrics["test/failure_rate"] <= 0.1, metrics


def test_warmup_cosine_schedule_and_configure_optimizers() -> None:
    """Linear warm-up to the base rate, cosine down to min_lr_ratio at the last step; an ExpertModule with a
    schedule hands Lightning the scheduler, stepped every optimisation step."""
    from functools import partial
    from types import SimpleNamespace

    from spade.training.expert_module import ExpertModule
    from spade.training.schedules import warmup_cosine, warmup_cosine_factor

    f = [warmup_cosine_factor(s, 100, 10, 0.01) for s in range(100)]
    assert f[0] == pytest.approx(0.1) and f[9] == pytest.approx(1.0)
    assert all(a >= b for a, b in zip(f[9:], f[10:]))
    assert f[-1] == pytest.approx(0.01 + 0.99 * 0.5 * (1 + np.cos(np.pi * 89 / 90)))
    assert warmup_cosine_factor(100, 100, 10, 0.01) == pytest.approx(0.01)

    module = ExpertModule(preset="tiny", optimizer=partial(torch.optim.AdamW, lr=1e-2),
                          lr_scheduler=partial(warmup_cosine, warmup_fraction=0.1, min_lr_ratio=0.0))
    module._trainer = SimpleNamespace(estimated_stepping_batches=20)
    out = module.configure_optimizers()
    opt, sched = out["optimizer"], out["lr_scheduler"]["scheduler"]
    assert out["lr_scheduler"]["interval"] == "step"
    lrs = []
    for _ in range(20):
        lrs.append(opt.param_groups[0]["lr"])
        opt.step()
        sched.step()
    assert lrs[0] == pytest.approx(5e-3) and lrs[1] == pytest.approx(1e-2) and max(lrs) == pytest.approx(1e-2)
    assert lrs[-1] < 1e-3
    assert not isinstance(ExpertModule(preset="tiny").configure_optimizers(), dict)  # no schedule: the optimiser


def test_cpu_scale_students_get_the_schedule_and_so_does_the_quickstart() -> None:
    """scale=cpu composes a warm-up + cosine schedule into every student (its validation curve jumped under a
    constant rate); the quickstart's student is Table 1's medium Cond-DBC recipe at that scale, schedule included."""
    from types import SimpleNamespace

    import hydra

    from spade.utils.config import compose_config
    from spade.training.student_module import StudentModule

    cfg = compose_config("train", ["+experiment=t1_small_bc_L", "scale=cpu"])
    assert cfg.model.lr_scheduler._target_ == "spade.training.schedules.warmup_cosine"
    student = hydra.utils.instantiate(cfg.model)
    assert isinstance(student, StudentModule) and student.lr_scheduler_factory is not None
    student._trainer = SimpleNamespace(estimated_stepping_batches=40)
    out = student.configure_optimizers()
    assert out["lr_scheduler"]["interval"] == "step"
    quick = compose_config("train", ["+experiment=quickstart"])
    table = compose_config("train", ["+experiment=t1_medium_conddbc_L", "scale=cpu"])
    assert quick.model.lr_scheduler == table.model.lr_scheduler
    assert quick.trainer.max_epochs == 2 and table.trainer.max_epochs == 6  # the quickstart's budget: a third of them
    for key in ("size", "bc_pos_weight", "optimizer", "lr_scheduler"):
        assert quick.model[key] == table.model[key], key
    assert {**quick.model.margin, "expert_ckpt": None, "lambda_dm": 0.3} == {**table.model.margin, "expert_ckpt": None,
                                                                           "lambda_dm": 0.3}
    assert quick.model.margin.lambda_dm == 0.3  # chosen on validation (README, Table 1's lambda grid)
    assert quick.model.margin.expert_ckpt.endswith("spade/models/weights/cond_expert_L_gaussian_cpu_lite_x0.ckpt")
    assert quick.data.encoding == table.data.encoding == "gaussian"  # the recipe's markers; the teacher's too
    assert quick.data.train_dir.endswith("/quickstart/lshape") and quick.data.batch_size == table.data.batch_size
