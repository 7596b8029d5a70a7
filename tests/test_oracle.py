"""The oracle teacher, the plausible set's images, the BC ceiling and the states without demonstrations."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from spade.data.labelled import StateView
from spade.data.plausible import ceiling_map, plausible_images
from spade.metrics.plausible import reference_maps
from spade.training.margin import DiffusionMargin, MarginConfig
from spade.training.oracle import OracleDenoiser, oracle_candidates


def _schedule(T: int = 1000) -> torch.Tensor:
    betas = torch.linspace(1e-4, 0.02, T, dtype=torch.float64)
    return torch.cumprod(1 - betas, 0)


def _add_noise(abar):
    def add(x0, noise, t):
        a = abar.to(x0.dtype)[t].view(-1, 1, 1, 1)
        return a.sqrt() * x0 + (1 - a).sqrt() * noise
    return add


def _lines(b: int = 2, n: int = 3, size: int = 16) -> tuple[torch.Tensor, torch.Tensor]:
    """Waypoints (b, K, 2) going up from the robot and alternatives (b, n, K, 2) bending left or right; the last
    alternative slot of the first instance empty (NaN)."""
    k = 8
    ys = torch.linspace(12, 3, k)
    demo = torch.stack([torch.full((k,), 8.0), ys], 1)
    waypoints = demo.expand(b, k, 2).clone()
    alts = torch.empty(b, n, k, 2)
    for j in range(n):
        bend = torch.linspace(0, (j - 1) * 3.0, k)
        alts[:, j] = torch.stack([8.0 + bend, ys], 1)
    alts[0, -1] = math.nan
    return waypoints, alts


def test_plausible_images_draw_the_demonstration_and_each_alternative() -> None:
    waypoints, alts = _lines()
    images, mask = plausible_images(waypoints, alts, 16, 16, width_px=1)
    assert images.shape == (2, 4, 1, 16, 16)
    assert mask.tolist() == [[True, True, True, False], [True, True, True, True]]
    assert images[0, 3].sum() == 0  # the empty slot stays empty
    assert images[0, 0, 0, 12, 8] == 1 and images[0, 0, 0, 3, 8] == 1  # the demonstration's column
    wide, _ = plausible_images(waypoints, alts, 16, 16, width_px=3)
    assert wide[0, 0, 0, 8, 7] == 1 and wide[0, 0, 0, 8, 9] == 1  # widened to 3 px like the training target


def test_the_ceiling_is_the_mean_of_the_valid_members() -> None:
    images = torch.zeros(1, 3, 1, 4, 4)
    images[0, 0, 0, 0, 0] = 1
    images[0, 1, 0, 0, 0] = 1
    images[0, 1, 0, 1, 1] = 1
    images[0, 2] = 1  # an empty slot, masked out
    mask = torch.tensor([[True, True, False]])
    ceiling = ceiling_map(images, mask)
    assert ceiling[0, 0, 0, 0] == 1.0 and ceiling[0, 0, 1, 1] == 0.5 and ceiling[0, 0, 2, 2] == 0.0


def test_reference_maps_without_alternatives_give_the_decoder_floor_only() -> None:
    path = torch.zeros(2, 1, 8, 8)
    path[:, 0, 2:6, 4] = 1
    maps = reference_maps({"path": path, "waypoints": torch.zeros(2, 4, 2)}, 3)
    assert set(maps) == {"demo_target"} and maps["demo_target"][0, 0, 3, 3] == 1


def test_the_oracle_is_the_exact_posterior_mean() -> None:
    """Against the formula computed by hand in float64 for two candidates."""
    abar = _schedule()
    oracle = OracleDenoiser(abar)
    g = torch.Generator().manual_seed(0)
    cands = torch.rand(1, 2, 1, 4, 4, generator=g, dtype=torch.float64) * 2 - 1
    mask = torch.tensor([[True, True]])
    t = torch.tensor([900])
    x_t = torch.randn(1, 1, 4, 4, generator=g, dtype=torch.float64)
    a = abar[900]
    d = [float(((x_t - a.sqrt() * cands[0, k]) ** 2).sum()) for k in range(2)]
    logits = [-dk / (2 * (1 - float(a))) for dk in d]
    w0 = 1 / (1 + math.exp(logits[1] - logits[0]))
    expected = w0 * cands[0, 0] + (1 - w0) * cands[0, 1]
    got = oracle(x_t, t, cands, mask)
    assert torch.allclose(got[0], expected, atol=1e-10)
    # at a low timestep it snaps to the candidate x_t came from; a masked candidate never counts
    x_low = abar[5].sqrt() * cands[:, 1] + (1 - abar[5]).sqrt() * 0.01 * torch.randn(1, 1, 4, 4, generator=g,
                                                                                       dtype=torch.float64)
    assert torch.allclose(oracle(x_low, torch.tensor([5]), cands, mask), cands[:, 1], atol=1e-6)
    only_first = oracle(x_low, torch.tensor([5]), cands, torch.tensor([[True, False]]))
    assert torch.allclose(only_first, cands[:, 0])


def _oracle_margin(**options) -> DiffusionMargin:
    abar = _schedule()
    config = MarginConfig(oracle=True, expert="conditional", **options)
    return DiffusionMargin(OracleDenoiser(abar), _add_noise(abar), 1000, True, config,
                           prediction_target=lambda x0, noise, t: x0)


def _plausible_batch():
    waypoints, alts = _lines(b=2, n=3, size=16)
    images, mask = plausible_images(waypoints, alts, 16, 16, width_px=3)
    state = torch.zeros(2, 3, 16, 16)
    return images, mask, state


def test_the_oracle_margin_is_zero_for_a_member_and_positive_for_a_blend() -> None:
    images, mask, state = _plausible_batch()
    margin = _oracle_margin(t_max=600)
    demo = images[:, 0]
    g = torch.Generator().manual_seed(1)
    same = margin.margins(demo, demo, state, generator=g, plausible=(images, mask))
    assert torch.allclose(same, torch.zeros(2), atol=1e-6)
    blend = ceiling_map(images, mask)  # no operator drew the mean of the set
    g = torch.Generator().manual_seed(1)
    worse = margin.margins(blend, demo, state, generator=g, plausible=(images, mask))
    assert (worse > 0).all()


def test_the_oracle_margin_teaches_the_student_through_its_prediction() -> None:
    images, mask, state = _plausible_batch()
    margin = _oracle_margin()
    logits = torch.zeros(2, 1, 16, 16, requires_grad=True)
    loss, _ = margin(torch.sigmoid(logits), images[:, 0], state, plausible=(images, mask))
    loss.backward()
    assert logits.grad is not None and logits.grad.abs().sum() > 0


def test_the_oracle_needs_the_plausible_set() -> None:
    images, mask, state = _plausible_batch()
    with pytest.raises(ValueError, match="alternatives"):
        _oracle_margin().margins(images[:, 0], images[:, 0], state)


def test_unlabelled_states_get_the_agent_term_alone_or_a_sample_as_reference() -> None:
    images, mask, state = _plausible_batch()
    blend = ceiling_map(images, mask)
    labelled = torch.tensor([True, False])
    nothing = torch.zeros_like(blend)  # an unlabelled state's target is never used
    agent = _oracle_margin(unlabelled="agent")
    g = torch.Generator().manual_seed(3)
    m = agent.margins(blend, nothing, state, generator=g, plausible=(images, mask), labelled=labelled)
    g = torch.Generator().manual_seed(3)
    t, noise = agent.draw(2, (1, 16, 16), blend.device, blend.dtype, g)
    alone = agent.denoising_error(blend * 2 - 1, noise, t, (oracle_candidates(images), mask))
    assert torch.isclose(m[1], alone[1], atol=1e-6)  # e_agent, the reference's error taken as 0
    sample = _oracle_margin(unlabelled="sample")
    m2 = sample.margins(images[:, 1], nothing, state, generator=torch.Generator().manual_seed(0),
                        plausible=(images, mask), labelled=labelled)
    assert torch.isfinite(m2).all()


def test_unlabelled_sample_needs_the_oracle() -> None:
    from spade.training.margin import MarginOptionError

    with pytest.raises(MarginOptionError, match="oracle"):
        MarginConfig(unlabelled="sample")
    with pytest.raises(MarginOptionError, match="unlabelled"):
        MarginConfig(oracle=True, unlabelled="teacher")


def test_a_state_view_marks_its_instances_and_pads_their_alternatives() -> None:
    items = [{"waypoints": torch.zeros(4, 2), "alternatives": torch.ones(2, 4, 2)}, {"waypoints": torch.zeros(4, 2)}]
    view = StateView(items, labelled=False, alternatives=3, num_waypoints=4)
    first, second = view[0], view[1]
    assert first["labelled"].item() is False
    assert first["alternatives"].shape == (3, 4, 2) and torch.isnan(first["alternatives"][2]).all()
    assert torch.isnan(second["alternatives"]).all()
    with pytest.raises(ValueError, match="slots"):
        StateView(items, True, alternatives=1)[0]


def test_a_student_learns_nothing_by_bc_from_unlabelled_states() -> None:
    """BC sees the labelled instances only: an unlabelled instance's target never moves the BC loss; without a
    margin, states without demonstrations are refused."""
    from spade.training.student_module import StudentModule

    torch.manual_seed(0)
    student = StudentModule(size="small")
    waypoints, alts = _lines(b=2, n=3, size=16)
    images, _, _ = _plausible_batch()
    state = torch.rand(2, 3, 16, 16)
    batch = {"state": state, "path": images[:, 0], "target": images[:, 0], "waypoints": waypoints,
             "alternatives": alts, "labelled": torch.tensor([True, False])}
    with pytest.raises(ValueError, match="unlabelled_dir"):
        student.losses(batch)
    student.margin_cfg = MarginConfig(oracle=True)
    student._margin[:] = [_oracle_margin()]
    first = student.losses(batch)["loss_bc"]
    changed = {**batch, "target": torch.stack([images[0, 0], torch.ones_like(images[1, 0])])}
    assert torch.isclose(first, student.losses(changed)["loss_bc"])
    assert torch.isclose(first, student.bc_loss(student(state)[:1], images[:1, 0]))


def test_bc_on_the_plausible_set_is_refused_without_alternatives() -> None:
    from spade.data.datamodule_options import DataOptions
    from spade.utils.errors import ConfigError

    with pytest.raises(ConfigError, match="target_source"):
        DataOptions(target_source="mean")
    assert DataOptions(target_source="plausible_mean").target_source == "plausible_mean"


def test_instance_rows_record_the_planner_figures() -> None:
    from spade.metrics.path_metrics import PathMetrics

    m = PathMetrics(fid=False, record_instances=True)
    waypoints, alts = _lines(b=2, n=3, size=16)
    images, mask = plausible_images(waypoints, alts, 16, 16, width_px=1)
    state = torch.zeros(2, 3, 16, 16)
    state[:, 0] = 0.5
    state[:, 1, 12, 8] = 1  # start and goal markers at the demonstration's ends
    state[:, 2, 3, 8] = 1
    polylines = [waypoints[0].numpy().astype(np.float64), None]
    batch = {"state": state, "path": images[:, 0], "waypoints": waypoints, "alternatives": alts,
             "resolution": torch.tensor([0.1, 0.1]), "scenario_id": ["a", "b"], "map_id": ["m", "m"]}
    m.update(images[:, 0], batch, polylines=polylines)
    rows = m.instance_rows
    assert [r["scenario"] for r in rows] == ["a", "b"]
    assert rows[0]["planner_ape_cm"] == pytest.approx(0.0) and rows[0]["planner_commit"] == 1.0
    assert rows[1]["planner_failed"] == 1.0 and rows[1]["planner_commit"] == 0.0
    m.reset()
    assert m.instance_rows == []


def test_the_medoid_is_the_central_drawn_path() -> None:
    from spade.metrics.preference import medoid_path

    ys = np.linspace(10, 0, 8)
    left, centre, right = (np.stack([np.full(8, x), ys], 1) for x in (0.0, 1.0, 3.0))
    assert medoid_path([left, right, centre, None]) is centre  # the one nearest all others, never a blend
    assert medoid_path([None]) is None and medoid_path([left]) is left


def test_the_oracle_as_a_planner_gives_a_genuine_alternative_and_the_medoid() -> None:
    from spade.metrics.plausible import reference_polylines

    waypoints, alts = _lines(b=2, n=3, size=16)
    refs = reference_polylines({"waypoints": waypoints, "alternatives": alts})
    assert np.allclose(refs["oracle_sample"][0], alts[0, 0].numpy())  # another draw, not the demonstration
    assert np.allclose(refs["oracle_medoid"][1][:, 0], 8.0)  # straight up: the centre of the bends -3, 0, +3
    assert reference_polylines({"waypoints": waypoints}) == {}


def _write_with_alternatives(root, n: int, seed: int, map_prefix: str) -> None:
    from factories import synthetic_instance

    from spade.data.writer import DatasetWriter

    rng = np.random.default_rng(seed)
    with DatasetWriter(root, image_size=32, resolution=0.05, num_waypoints=16, generator_config={"seed": seed},
                       alternatives=2, alternatives_info={"count": 2}) as w:
        for i in range(n):
            inst = synthetic_instance(rng, 32, 16)
            bent = inst["waypoints"].copy()
            bent[1:-1, 0] += 1.5  # another way to the same goal
            labels = {"shape": "L", "map_id": f"{map_prefix}{i % 2}", "scenario_id": f"{map_prefix}{i % 2}/s{i}"}
            w.add(**inst, **labels, alternatives=np.stack([bent]))


def test_a_student_trains_with_the_oracle_on_labelled_and_unlabelled_states(tmp_path) -> None:
    """The whole path of the site rows at a tiny size: a training set and a set of states without demonstrations,
    both with alternatives, in one loader; the oracle margin on every state, BC on the labelled ones."""
    import lightning as L

    from spade.data.datamodule import PathDataModule
    from spade.training.expert_module import ExpertModule
    from spade.training.student_module import StudentModule

    _write_with_alternatives(tmp_path / "train", 12, 0, "a")
    _write_with_alternatives(tmp_path / "unlabelled", 8, 1, "b")
    _write_with_alternatives(tmp_path / "test", 4, 2, "c")
    dm = PathDataModule(tmp_path / "train", tmp_path / "test", val_fraction=0.25, batch_size=8, target_width_px=3,
                        unlabelled_dir=tmp_path / "unlabelled", max_unlabelled_instances=6)
    dm.setup("fit")
    assert len(dm.train_set) > 6 and dm.unlabelled_count == 6
    labelled = torch.cat([b["labelled"] for b in dm.train_dataloader()])
    assert int((~labelled).sum()) == 6 and bool(labelled.any())
    placeholder = tmp_path / "expert.ckpt"  # the expert is given below (use_expert), never loaded from here
    placeholder.touch()
    student = StudentModule(size="small", margin={"oracle": True, "t_max": 600, "expert_ckpt": str(placeholder)},
                            metrics={"fid": False}, grid_size=0)
    expert = ExpertModule(conditional=True, preset="tiny", metrics={"fid": False, "planner": False})
    student.use_expert(expert)  # lends its schedule; the oracle stands in for its network
    trainer = L.Trainer(max_steps=4, accelerator="cpu", logger=False, enable_checkpointing=False,
                        enable_progress_bar=False, num_sanity_val_steps=0, limit_val_batches=0)
    trainer.fit(student, datamodule=dm)
    assert student.margin_history and 0.0 <= student.margin_history[-1][1] <= 1.0
    assert all(math.isfinite(v) for _, _, v in student.margin_history)


def test_every_site_row_composes_and_its_variants_change_only_what_they_name(tmp_path) -> None:
    """The oracle page's rows (conf/experiment/site_*.yaml) compose and pass spade.train's checks; a lambda, t or
    data-size variant differs from its parent row only in that setting and its run name."""
    from omegaconf import OmegaConf

    from spade.config.preflight import validate_train_config
    from spade.paths import CONF_DIR
    from training_helpers import compose_row

    rows = sorted(p.stem for p in (CONF_DIR / "experiment").glob("site_*_L.yaml"))
    composed = {}
    for row in rows:
        extra = ["model.margin.expert_ckpt=/nonexistent.ckpt"] if "richteacher" in row else \
            ["data.unlabelled_teacher=/nonexistent.ckpt"] if "richlabels" in row else []
        cfg = compose_row(row, tmp_path, "logger=none", *extra)
        assert cfg.run_name == row and cfg.tags.table == "oracle"
        if not extra:
            validate_train_config(cfg)
        composed[row] = OmegaConf.to_container(cfg, resolve=False)

    def differences(a: dict, b: dict, prefix: str = "") -> set[str]:
        keys = set(a) | set(b)
        out = set()
        for k in keys:
            x, y = a.get(k), b.get(k)
            if isinstance(x, dict) and isinstance(y, dict):
                out |= differences(x, y, f"{prefix}{k}.")
            elif x != y:
                out.add(f"{prefix}{k}")
        return out

    ignore = {"run_name", "paths.output_dir", "tags.row"}
    expected = {"site_oracle_lam01_L": ("site_oracle_L", {"model.margin.lambda_dm"}),
                "site_oracle_lam10_L": ("site_oracle_L", {"model.margin.lambda_dm"}),
                "site_oracle_allt_L": ("site_oracle_L", {"model.margin.t_max"}),
                "site_bc_250_L": ("site_bc_L", {"data.max_train_instances"}),
                "site_bcplaus_250_L": ("site_bcplaus_L", {"data.max_train_instances"})}
    steps = {"data.max_train_instances", "trainer.max_epochs", "trainer.max_steps"}
    every_32 = {"trainer.check_val_every_n_epoch", "trainer.val_check_interval"}
    for parent in ("site_bc_L", "site_bcplaus_L"):
        row = parent.removesuffix("_L")
        expected[f"{row}_1000_L"] = (parent, steps)
        expected[f"{row}_2000_L"] = (parent, steps | every_32)
        expected[f"{row}_250steps_L"] = (f"{row}_250_L", {"trainer.max_epochs"})
    for row in ("site_bc", "site_bcplaus", "site_oraclelabels"):
        expected[f"{row}_small_L"] = (f"{row}_L", {"model.size"})
    for row, (parent, keys) in expected.items():
        assert differences(composed[row], composed[parent]) - ignore == keys, row


def test_a_teachers_medoid_plans_label_the_unsketched_states_once(tmp_path, tiny_checkpoints) -> None:
    """data.unlabelled_teacher: the states without demonstrations get the medoid of the expert's decoded samples as
    their label, from the robot's start to the goal, written once beside the unlabelled set and reused; BC sees them
    as labelled states. A student checkpoint, or the option without unlabelled_labels, is refused by name."""
    from spade.data.datamodule import PathDataModule
    from spade.data.format import DatasetError
    from spade.data.path_dataset import PathDataset
    from spade.training.teacher_labels import ensure_teacher_labels, label_unlabelled

    _write_with_alternatives(tmp_path / "train", 12, 0, "a")
    _write_with_alternatives(tmp_path / "unlabelled", 8, 1, "b")
    _write_with_alternatives(tmp_path / "test", 4, 2, "c")
    source = PathDataset(tmp_path / "unlabelled")
    out = ensure_teacher_labels(tiny_checkpoints["cond"], tmp_path / "unlabelled", 2, 6, "binary")
    labels = PathDataset(out)
    info = labels.manifest.generator["teacher_labels"]
    assert info["samples"] == 2 and info["states"] == 6 and len(labels) + labels.manifest.extra[
        "teacher_labels_left_out"] == 6
    assert labels.manifest.alternatives == 0  # the generator's alternatives are the oracle's, never copied
    scenarios = source.labels("scenario_id")
    for i in range(len(labels)):
        got = labels[i]
        src = source[scenarios.index(got["scenario_id"])]
        assert torch.equal(got["state"], src["state"])  # the same window, start and goal: only the label is new
        assert got["path"].sum() > 0 and got["waypoints"].shape == src["waypoints"].shape
        for end in (0, -1):  # the teacher's plan runs from the robot's start to the goal
            assert float(torch.linalg.norm(got["waypoints"][end] - src["waypoints"][end])) < 1.5
    stamp = (out / "manifest.json").stat().st_mtime_ns
    assert ensure_teacher_labels(tiny_checkpoints["cond"], tmp_path / "unlabelled", 2, 6, "binary") == out
    assert (out / "manifest.json").stat().st_mtime_ns == stamp  # sampled once, then read

    dm = PathDataModule(tmp_path / "train", tmp_path / "test", val_fraction=0.25, batch_size=8,
                        unlabelled_dir=tmp_path / "unlabelled", max_unlabelled_instances=6, unlabelled_labels=True,
                        unlabelled_teacher=tiny_checkpoints["cond"], unlabelled_teacher_samples=2)
    with pytest.raises(DatasetError, match="its labels are not made yet"):
        dm.setup("fit")
    assert label_unlabelled(dm) == out  # the same teacher, samples and states: the labels already made
    dm.setup("fit")
    assert dm.unlabelled_count == len(labels)
    assert all(bool(b["labelled"].all()) for b in dm.train_dataloader())
    with pytest.raises(ValueError, match="data.unlabelled_labels=true"):
        PathDataModule(tmp_path / "train", unlabelled_dir=tmp_path / "unlabelled",
                       unlabelled_teacher=tiny_checkpoints["cond"])
    with pytest.raises(DatasetError, match="is a student checkpoint"):
        ensure_teacher_labels(tiny_checkpoints["student"], tmp_path / "unlabelled", 2, 3, "binary")
    with pytest.raises(DatasetError, match="does not exist"):
        ensure_teacher_labels(tmp_path / "missing.ckpt", tmp_path / "unlabelled", 2, 3, "binary")


def test_the_teacher_label_row_is_refused_before_it_starts_without_a_teacher(tmp_path) -> None:
    from spade.config.preflight import validate_train_config
    from spade.utils.errors import ConfigError
    from training_helpers import compose_row

    cfg = compose_row("site_richlabels_L", tmp_path, "logger=none", f"data.unlabelled_teacher={tmp_path}/none.ckpt")
    with pytest.raises(ConfigError, match=r"data.unlabelled_teacher=.*none.ckpt does not exist"):
        validate_train_config(cfg)
    cfg = compose_row("site_richlabels_L", tmp_path, "logger=none", f"data.unlabelled_teacher={tmp_path}/none.ckpt",
                      "data.unlabelled_labels=false")
    with pytest.raises(ConfigError, match="data.unlabelled_labels=true with it"):
        validate_train_config(cfg)
