"""The expert as a critic: the corruption set, the critic's figures against critics of known behaviour, the margin's
scores and straight-through input, and the per-epoch guidance activity of a guided student."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from torch import nn

from spade.data.augment import widen_path
from spade.metrics.baselines import draw_polylines
from spade.metrics.corruptions import CORRUPTIONS, corrupt, gaussian_blur, shift_images, turn_point, wider_turn
from spade.training.critic import band_edges, critic_metrics, measure_errors
from spade.training.margin import DiffusionMargin, MarginConfig
from spade.tracking.predictors import TOP_LEVEL_FILTER

SIZE = 32
ROBOT_X = 16.0


def l_path(corner=(16.0, 8.0), start=(16.0, 24.0), goal=(28.0, 8.0), k: int = 24) -> np.ndarray:
    """An L in window pixels: up from the robot, a right angle, then right to the goal, resampled to ``k`` points."""
    from spade.data.polyline import resample_polyline

    return resample_polyline(np.array([start, corner, goal], np.float64), k)


def batch_of(paths: list[np.ndarray]) -> dict:
    """A batch with these paths: occupancy free everywhere, start and goal discs, 1 px path, waypoints."""
    n = len(paths)
    path = draw_polylines(paths, SIZE, SIZE)
    state = torch.zeros(n, 3, SIZE, SIZE)
    state[:, 0] = 0.5
    for i, p in enumerate(paths):
        for channel, (x, y) in ((1, p[0]), (2, p[-1])):
            state[i, channel, int(round(y)) - 1:int(round(y)) + 2, int(round(x)) - 1:int(round(x)) + 2] = 1.0
    return {"state": state, "path": path, "waypoints": torch.tensor(np.stack(paths), dtype=torch.float32),
            "resolution": torch.full((n,), 0.1)}


# -- the corruptions --------------------------------------------------------------------------------------------
def test_every_corruption_changes_an_l_and_keeps_the_value_range() -> None:
    b = batch_of([l_path()])
    target = widen_path(b["path"], 3)
    for name in CORRUPTIONS:
        out = corrupt(name, target, b["waypoints"], ROBOT_X, 3)
        assert out.shape == target.shape and out.min() >= 0 and out.max() <= 1, name
        assert (out - target).abs().sum() >= 1.0, f"{name} left the L unchanged"


def test_blur_keeps_the_peak_and_spreads_the_path_faint_halves_it() -> None:
    b = batch_of([l_path()])
    target = widen_path(b["path"], 3)
    blur = corrupt("blur", target, b["waypoints"], ROBOT_X, 3)
    assert float(blur.max()) == pytest.approx(1.0)
    assert int((blur > 0.05).sum()) > int((target > 0.5).sum())  # wider
    assert torch.equal(corrupt("faint", target, b["waypoints"], ROBOT_X, 3), 0.5 * target)
    assert float(gaussian_blur(target, 1.5).sum()) == pytest.approx(float(target.sum()), rel=0.02)  # mass kept


def test_shift_moves_the_path_by_the_given_pixels() -> None:
    image = torch.zeros(1, 1, 8, 8)
    image[0, 0, 3, 3] = 1.0
    moved = shift_images(image, torch.tensor([[2, -1]]))
    assert moved[0, 0, 2, 5] == 1.0 and moved.sum() == 1.0
    b = batch_of([l_path()])
    target = widen_path(b["path"], 3)
    shifted = corrupt("shift3", target, b["waypoints"], ROBOT_X, 3, seed=5)
    ys, xs = torch.nonzero(target[0, 0] > 0.5, as_tuple=True)
    ys2, xs2 = torch.nonzero(shifted[0, 0] > 0.5, as_tuple=True)
    assert max(abs(float(xs2.float().mean() - xs.float().mean())), abs(float(ys2.float().mean() - ys.float().mean()))) \
        == pytest.approx(3.0, abs=0.6)


def test_a_straight_path_is_its_own_mirror_image_and_straight_line() -> None:
    straight = l_path(corner=(16.0, 16.0), goal=(16.0, 4.0))
    b = batch_of([straight])
    target = widen_path(b["path"], 3)
    for name in ("mirror", "straight", "radius"):
        assert (corrupt(name, target, b["waypoints"], ROBOT_X, 3) - target).abs().sum() < 1.0, name
    assert turn_point(straight) == 0.5


def test_gap_is_cut_at_the_turn_and_the_wider_turn_keeps_the_ends() -> None:
    p = l_path()
    assert turn_point(p) == pytest.approx(16 / 28, abs=0.05)  # the corner: 16 px up, then 12 px right
    b = batch_of([p])
    target = widen_path(b["path"], 3)
    gap = corrupt("gap", target, b["waypoints"], ROBOT_X, 3)
    assert float(gap[0, 0, 8, 16]) == 0.0 and float(target[0, 0, 8, 16]) == 1.0  # the corner pixel is gone
    assert float(gap[0, 0, 22, 16]) == 1.0  # the start of the path is kept
    wide = wider_turn(p)
    assert np.allclose(wide[0], p[0]) and np.allclose(wide[-1], p[-1])
    corner_distance = np.min(np.linalg.norm(wide - np.array([16.0, 8.0]), axis=1))
    assert corner_distance > 3.0  # the corner is cut wide


def test_an_unknown_corruption_names_the_set() -> None:
    b = batch_of([l_path()])
    with pytest.raises(ValueError, match="unknown corruption 'fuzz'.*blur"):
        corrupt("fuzz", b["path"], b["waypoints"], ROBOT_X, 3)


# -- the critic against critics of known behaviour --------------------------------------------------------------
class FixedPrediction(nn.Module):
    """An x0-predicting 'expert' that always predicts ``image`` (in the model's [-1, 1] range), whatever its input:
    its denoising error for a candidate x0 is ||image - x0||^2, so it ranks candidates by their distance to it."""

    def __init__(self, image: torch.Tensor) -> None:
        super().__init__()
        self.register_buffer("image", image)

    def forward(self, x, t, cond=None):  # the critic stacks candidates: [demo; c1; c2; ...] of one batch each
        image = self.image if self.image.dim() else self.image.expand_as(x)
        return image.repeat(x.shape[0] // image.shape[0], 1, 1, 1)


def _margin(image: torch.Tensor, **options) -> DiffusionMargin:
    return DiffusionMargin(FixedPrediction(image), lambda x0, noise, t: x0, 100, True, MarginConfig(**options),
                           prediction_target=lambda x0, noise, t: x0)


def _paths() -> list[np.ndarray]:
    return [l_path(), l_path(goal=(4.0, 8.0)), l_path(corner=(16.0, 12.0), goal=(26.0, 12.0)),
            l_path(corner=(16.0, 16.0), goal=(16.0, 4.0))]  # the last is straight


def test_a_critic_that_predicts_the_demonstration_ranks_it_above_every_corruption() -> None:
    b = batch_of(_paths())
    demo = widen_path(b["path"], 3) * 2 - 1
    errors = measure_errors(_margin(demo), [b], ROBOT_X, 3, draws_per_band=1, bands=4)
    m = critic_metrics(errors, _margin(demo))
    for name in CORRUPTIONS:
        assert m[f"critic/win/{name}"] == 1.0, name
    assert m["critic/tie/mirror"] == pytest.approx(0.25) and m["critic/tie/straight"] == pytest.approx(0.25)
    assert m["critic/win_min"] == 1.0
    assert errors.t.shape == (4, 4) and [lo for lo, _ in errors.bands] == [0, 25, 50, 75]
    for i, (lo, hi) in enumerate(errors.bands):
        assert ((errors.t[:, i] >= lo) & (errors.t[:, i] < hi)).all()


def test_a_critic_that_prefers_blur_is_caught() -> None:
    b = batch_of(_paths()[:3])
    target = widen_path(b["path"], 3)
    blurred = corrupt("blur", target, b["waypoints"], ROBOT_X, 3) * 2 - 1
    soft = _margin(blurred)
    m = critic_metrics(measure_errors(soft, [b], ROBOT_X, 3, corruptions=["blur", "shift3"], bands=2), soft)
    assert m["critic/win/blur"] == 0.0 and m["critic/ratio/blur"] < 1.0
    assert m["critic/win/shift3"] == 1.0 and m["critic/win_min"] == 0.0


def test_a_students_margin_activity_and_its_rank_correlation_with_ape() -> None:
    b = batch_of(_paths()[:3])
    demo = widen_path(b["path"], 3)

    class Student(nn.Module):  # the demonstration for the first instance, worse and worse after
        def forward(self, state):
            logits = (demo * 2 - 1) * 8
            logits[1] = torch.roll(logits[1], 2, dims=-1)
            logits[2] = torch.roll(logits[2], 5, dims=-1)
            return logits

    margin = _margin(demo * 2 - 1, agent_input="straight_through")  # the first prediction is then the demonstration
    errors = measure_errors(margin, [b], ROBOT_X, 3, corruptions=[], student=Student(), bands=1)
    m = critic_metrics(errors, margin)
    assert m["critic/win/student"] == pytest.approx(2 / 3)
    assert m["critic/student/margin"] > 0
    assert m["critic/student/spearman_ape"] == pytest.approx(1.0)
    # the planner's reading: the decoded path of the worse predictions is further from the demonstration too
    assert m["critic/student/spearman_planner_ape"] == pytest.approx(1.0)
    # the same draws under every score: the search over formulations without a training run each
    for score in ("difference", "log_ratio", "relative"):
        assert -1.0 <= m[f"critic/search/spearman_planner_ape/{score}"] <= 1.0
    assert m["critic/search/spearman_planner_ape/difference"] == pytest.approx(m["critic/student/spearman_planner_ape"])
    assert "critic/student/spearman_plausibility" not in m  # no alternatives: no plausibility to rank by


def test_the_margins_rank_correlation_with_plausibility_sees_a_plausible_other_turn() -> None:
    """A student that draws an alternative demonstration is wrong by APE but plausible: the plausibility error
    (against the nearest plausible path) is ~0 there, and the Spearman against it is computed per instance."""
    paths = _paths()[:4]
    b = batch_of(paths)
    demo = widen_path(b["path"], 3)
    other = paths[0].copy()  # instance 0's alternative: the same start and goal, bowed up to 4 px to the side
    other[:, 0] += 4.0 * np.sin(np.linspace(0.0, np.pi, len(other)))
    alternatives = torch.full((4, 1, *b["waypoints"].shape[1:]), float("nan"))
    alternatives[0, 0] = torch.tensor(other, dtype=torch.float32)
    for i in (1, 2, 3):
        alternatives[i, 0] = b["waypoints"][i] + 9.0  # far from anything the student draws
    b["alternatives"] = alternatives
    drawn = widen_path(draw_polylines([other, *paths[1:]], SIZE, SIZE), 3)

    class Student(nn.Module):  # instance 0: the alternative; the others: the demonstration
        def forward(self, state):
            return (drawn * 2 - 1) * 8

    margin = _margin(demo * 2 - 1, agent_input="straight_through")
    errors = measure_errors(margin, [b], ROBOT_X, 3, corruptions=[], student=Student(), bands=1)
    assert errors.planner_ape_cm[0] > 15.0  # up to 4 px = 40 cm from the demonstration
    assert errors.plausibility_cm[0] < 0.25 * errors.planner_ape_cm[0]  # ... but next to a plausible one
    m = critic_metrics(errors, margin)
    assert -1.0 <= m["critic/student/spearman_plausibility"] <= 1.0
    assert m["critic/student/plausibility_cm"] < m["critic/student/planner_ape_cm"]


def test_band_edges_cover_the_range() -> None:
    assert band_edges(0, 1000, 5) == [(0, 200), (200, 400), (400, 600), (600, 800), (800, 1000)]
    assert band_edges(10, 13, 5) == [(10, 11), (11, 12), (12, 13)]
    with pytest.raises(ValueError):
        band_edges(0, 10, 0)


# -- the margin's scores and input -------------------------------------------------------------------------------
@pytest.mark.parametrize("score", ["difference", "log_ratio", "relative"])
def test_every_score_is_zero_for_the_demonstration_and_agrees_in_sign(score: str) -> None:
    margin = _margin(torch.zeros(1), score=score)
    e_demo = torch.tensor([0.5, 0.5, 0.5])
    e_agent = torch.tensor([0.5, 0.8, 0.2])
    s = margin.score(e_agent, e_demo)
    assert s[0] == 0 and s[1] > 0 and s[2] < 0


def test_straight_through_input_is_binary_forward_and_passes_the_gradient() -> None:
    margin = _margin(torch.zeros(1), agent_input="straight_through")
    prob = torch.tensor([0.2, 0.6, 0.9], requires_grad=True)
    out = margin.agent_path(prob)
    assert out.tolist() == [0.0, 1.0, 1.0]
    out.sum().backward()
    assert prob.grad.tolist() == [1.0, 1.0, 1.0]


def test_bad_formulation_options_name_the_option() -> None:
    from spade.training.margin import MarginOptionError

    with pytest.raises(MarginOptionError, match="score='ratio' is not one of"):
        MarginConfig(score="ratio")
    with pytest.raises(MarginOptionError, match="agent_input='hard' is not one of"):
        MarginConfig(agent_input="hard")


def test_the_run_summary_says_whether_guidance_acted_to_the_end() -> None:
    from spade.tracking.summary import guidance_line

    assert guidance_line(None) is None and guidance_line([]) is None
    died = guidance_line([(0, 1.0, 0.5), (1, 0.0, 0.0)])
    assert "0: 100%" in died and "1: 0%" in died and "stopped acting" in died
    assert "acted to the end" in guidance_line([(0, 1.0, 0.5), (1, 0.42, 0.01)])


def test_the_run_description_says_in_words_whether_guidance_acted(spade_home) -> None:
    """Once, whether guidance acted was hidden in the 10th chart section; the MLflow description says it."""
    from spade.tracking.descriptions import run_description
    from training_helpers import compose_row

    cfg = compose_row("t1_small_conddbc_L", spade_home, "logger=none")
    text = run_description(cfg, {"test/ape_cm": 5.0}, [], [], margin_history=[(0, 1.0, 0.5), (1, 0.0, 0.0)])
    assert "Guidance: margin active by epoch  0: 100%  1: 0%  -> stopped acting" in text
    assert "Guidance" not in run_description(cfg, {"test/ape_cm": 5.0}, [], [])


# -- the command -------------------------------------------------------------------------------------------------
def _critic_cfg(spade_home, *overrides: str):
    from omegaconf import open_dict

    from spade.utils.config import compose_config

    cfg = compose_config("critic", ["scale=tiny", "logger=none", "critic.max_instances=6", "critic.bands=2",
                                    "critic.draws_per_band=1", f"output_dir={spade_home}/critic", *overrides])
    with open_dict(cfg):
        cfg.paths.output_dir = str(spade_home / "critic_out")
    return cfg


def _win_rates(bands: dict[str, tuple[float, ...]]) -> dict[str, float]:
    """Canned critic figures: each candidate's win rate per band (t0000-0200 ...) and over all timesteps."""
    out = {}
    for name, wins in bands.items():
        out[f"critic/win/{name}"] = sum(wins) / len(wins)
        for i, win in enumerate(wins):
            out[f"critic/win/{name}/t{200 * i:04d}-{200 * (i + 1):04d}"] = win
    return out


def test_the_critic_verdict_says_whether_the_expert_ranks_the_demonstration_first_in_most_bands() -> None:
    from spade.experiments.critic_run import critic_verdict

    good = _win_rates({"blur": (0.92, 0.93, 0.79, 0.53, 0.33), "shift1": (1.0, 1.0, 1.0, 1.0, 0.98),
                       "empty": (1.0,) * 5, "student": (0.05, 0.04, 0.04, 0.03, 0.01)})
    text = critic_verdict(good)
    assert text.startswith("The expert ranks the demonstration above each of its 3 corruptions in most of 5 "
                           "timestep bands")
    assert "Its weakest is blur: a win rate of 70% over all timesteps, 33% in band t 0800-1000." in text
    assert text.endswith("Against the student, the demonstration scores better on 3% of the instances: the share "
                         "where the margin acts.")
    mixed = _win_rates({"blur": (0.4, 0.3, 0.6, 0.2, 0.1), "shift1": (0.9,) * 5, "empty": (1.0,) * 5})
    assert critic_verdict(mixed).startswith("The expert ranks the demonstration above 2 of its 3 corruptions in most "
                                            "of 5 timestep bands, but not above blur.")
    bad = _win_rates({"blur": (0.4, 0.3, 0.6, 0.2, 0.1), "shift1": (0.5,) * 5, "empty": (0.9,) * 5})
    text = critic_verdict(bad)
    assert text.startswith("The expert does not rank the demonstration above its corruptions: it does so in most of "
                           "5 timestep bands for only 1 of 3 (empty).")
    assert "student" not in text and len(text.split(". ")) == 2


def test_critic_command_scores_an_expert_and_a_student_and_writes_its_page(spade_home, tiny_checkpoints) -> None:
    from spade.experiments.critic_run import critic, critic_verdict, format_report

    cfg = _critic_cfg(spade_home, f"ckpt_path={tiny_checkpoints['cond']}", f"student_ckpt={tiny_checkpoints['student']}",
                      "margin=cond_dbc_st")
    metrics = critic(cfg)
    assert metrics["critic/instances"] == 6.0
    for name in CORRUPTIONS:
        assert 0.0 <= metrics[f"critic/ratio/{name}"] and f"critic/win/{name}/t0000-0500" in metrics
    assert 0.0 <= metrics["critic/win/student"] <= 1.0 and "critic/student/spearman_ape" in metrics
    pages = list((spade_home / "critic").glob("critic_*_straight_through_difference_student.md"))
    assert len(pages) == 1 and (pages[0].with_suffix(".png")).is_file()
    text = pages[0].read_text()
    assert "| blur |" in text and "- commit: " in text and "- wall time: " in text
    assert "Provenance:\n\n- command: " in text and "Student:\n\n- " in text  # lists after a blank line
    assert str(spade_home) not in text  # paths relative to SPADE_HOME (spade.utils.provenance.shown_path)
    assert text.split("\n")[2:4] == ["## Verdict", ""] and text.split("\n")[4].startswith(critic_verdict(metrics))
    # the expert as a planner beside the student, on the same instances (spade.training.teacher)
    for key in ("expert/planner/ape_cm", "expert/mean_map/planner/ape_cm", "student/planner/ape_cm",
                "expert/spread_cm", "expert/seconds_per_sample"):
        assert key in metrics and metrics[key] >= 0.0, key
    assert metrics["expert/instances"] == 6.0
    assert "| expert, one sample |" in text and "| student |" in text and "generator's" in text
    # a rerun replaces the page SPADE wrote only with overwrite=true (checked before any measuring)
    from spade.config.critic_checks import validate_critic_config
    from spade.utils.errors import ConfigError

    with pytest.raises(ConfigError, match="pass overwrite=true"):
        validate_critic_config(cfg)
    assert "blur" in format_report(metrics)


def test_critic_command_refuses_a_student_as_expert_and_a_missing_test_set(spade_home, tiny_checkpoints) -> None:
    from spade.experiments.critic_run import critic
    from spade.data import DatasetError

    with pytest.raises(ValueError, match="not an expert checkpoint|expert"):
        critic(_critic_cfg(spade_home, f"ckpt_path={tiny_checkpoints['student']}"))
    with pytest.raises(DatasetError, match="data.test_dir=.*holds no dataset"):
        critic(_critic_cfg(spade_home, f"ckpt_path={tiny_checkpoints['cond']}", f"data.test_dir={spade_home}/none"))
    with pytest.raises(Exception, match="agent_input"):
        critic(_critic_cfg(spade_home, f"ckpt_path={tiny_checkpoints['cond']}", "+model.margin.agent_input=soft"))


@pytest.mark.slow
def test_a_guidance_row_tests_its_checkpoint_on_real_maps_as_a_run_of_its_seed(spade_home, maps_dir) -> None:
    """also_test: the best checkpoint tested on data=realmap_L as run <row>_real in the same MLflow experiment,
    carrying the row's seed, so that spade.report counts it per seed."""
    from mlflow import MlflowClient

    from spade.experiments.run import train
    from training_helpers import compose_row

    cfg = compose_row("g_few_conddbcst_L", spade_home, "trainer.max_epochs=1", "data.max_train_instances=32",
                      "seed=7", "trainer.enable_progress_bar=false", "model.grid_size=0",
                      "callbacks.model_info.latency_runs=0")
    metrics, objects = train(cfg)
    assert "real/test/ape_cm" in metrics and "test/ape_cm" in metrics
    assert objects["model"].margin_history and objects["model"].margin_history[0][0] == 0
    client = MlflowClient(tracking_uri=str(cfg.paths.mlflow_tracking_uri))
    exp = client.get_experiment_by_name("guidance")
    runs = {r.info.run_name: r for r in client.search_runs([exp.experiment_id], filter_string=TOP_LEVEL_FILTER)}
    real = runs["g_few_conddbcst_L_real"]
    assert real.info.status == "FINISHED" and real.data.params["cfg/seed"] == "7"
    assert real.data.metrics["test/ape_cm"] == pytest.approx(metrics["real/test/ape_cm"])
    history = client.get_metric_history(runs["g_few_conddbcst_L"].info.run_id, "margin/active")
    assert len(history) == 1  # one epoch: one value, at its validation's global step (margin/* shares val's x axis)


def test_the_oracle_as_a_critic_ranks_the_demonstration_above_the_blurred_and_the_faint() -> None:
    """The exact denoiser of each instance's plausible set (here the demonstration alone): at low noise it snaps a
    corrupted path back to the demonstration, so the demonstration's error is the smaller."""
    from spade.training.oracle import OracleDenoiser

    b = batch_of(_paths())
    b["alternatives"] = torch.full((4, 2, b["waypoints"].shape[1], 2), float("nan"))
    betas = torch.linspace(1e-4, 0.02, 1000, dtype=torch.float64)
    abar = torch.cumprod(1 - betas, 0)

    def add_noise(x0, noise, t):
        a = abar.to(x0.dtype)[t].view(-1, 1, 1, 1)
        return a.sqrt() * x0 + (1 - a).sqrt() * noise

    margin = DiffusionMargin(OracleDenoiser(abar), add_noise, 1000, True, MarginConfig(oracle=True, t_max=300),
                             prediction_target=lambda x0, noise, t: x0)
    errors = measure_errors(margin, [b], ROBOT_X, 3, draws_per_band=2, bands=2)
    m = critic_metrics(errors, margin)
    assert m["critic/win/blur"] == 1.0 and m["critic/win/faint"] == 1.0
    del b["alternatives"]
    with pytest.raises(ValueError, match="alternative"):
        measure_errors(margin, [b], ROBOT_X, 3, draws_per_band=1, bands=1)
