"""Every experiment composes and instantiates; every Table 1-3 row runs one batch of each stage at tiny scale."""

from __future__ import annotations

from pathlib import Path

import hydra
import pytest
import torch

from spade.paths import CONF_DIR
import spade.experiments.multirun  # noqa: F401  (registers the tables' ${spade_sweep:} and ${spade_rows:})
from spade.experiments.run import train
from training_helpers import compose_row

TABLES = {"table1": 22, "ablation_finetune": 3, "ablation_scratch": 2}
ROWS = sorted(p.stem for p in (CONF_DIR / "experiment").glob("*.yaml") if p.stem.startswith(("t1_", "t2_", "t3_", "cond_expert_", "uncond_expert_")))


def test_there_is_one_experiment_per_row() -> None:
    """Each table's rows are listed once (spade/tracking/tables.py): its composition sweeps them, and every one
    of them is an experiment file."""
    from spade.tracking.tables import TABLES

    assert len(ROWS) == 27  # 18 students + 4 experts + 3 (Table 2) + 2 (Table 3)
    assert set(FAST_ROWS) <= set(ROWS)
    listed = [row for key in ("table1", "table2", "table3") for row in TABLES[key].sweep_order]
    assert sorted(listed) == ROWS


@pytest.mark.parametrize("table,count", sorted(TABLES.items()))
def test_table_compositions_launch_their_rows(table: str, count: int, spade_home: Path) -> None:
    cfg = compose_row(table, spade_home, hydra_config=True)
    rows = cfg.hydra.sweeper.params.experiment.split(",")
    assert cfg.hydra.mode.name == "MULTIRUN" and len(rows) == count
    assert all(r in ROWS for r in rows)


def _fill_requirements(cfg, ckpts: dict[str, str]) -> list[str]:
    out = []
    for req in (cfg.get("requires") or {}).values():
        if req.target == "model.init_ckpt":
            out.append(f"model.init_ckpt={ckpts['student']}")
        else:
            key = "uncond" if "uncond" in req.experiment else "cond"
            out.append(f"model.margin.expert_ckpt={ckpts[key]}")
    return out


# One row per code path runs through fast_dev_run (an expert through its test stage, the conditional one is fitted
# by the tiny_checkpoints fixture; BC, DBC and Cond-DBC students; a fine-tuned ablation row with the margin); every
# row composes and instantiates (the test after it): the other rows differ from these only in sizes and shapes,
# which that covers without fitting a 31M-parameter student on a CPU.
FAST_ROWS = ["uncond_expert_U", "t1_small_bc_L", "t1_small_dbc_U", "t1_small_conddbc_L", "t2_augbc_finetune_conddbc_U"]
# One batch of each stage, small batches, two prediction pictures, two latency runs: every code path, in seconds.
FDR = ["debug=fdr", "logger=none", "data.batch_size=4", "data.eval_batch_size=8", "model.grid_size=2",
       "callbacks.model_info.latency_runs=2"]


@pytest.mark.parametrize("row", FAST_ROWS)
def test_row_composes_instantiates_and_runs_fast_dev_run(row: str, spade_home: Path, tiny_checkpoints: dict) -> None:
    cfg = compose_row(row, spade_home)
    cfg = compose_row(row, spade_home, *FDR, *_fill_requirements(cfg, tiny_checkpoints))
    assert cfg.tags.table in ("table1", "table2", "table3")
    metrics, objects = train(cfg)
    assert "test/ape_cm" in metrics and "test/hd19" in metrics
    model = objects["model"]
    if cfg.model.get("margin"):
        assert model.margin is not None
        assert all(not p.requires_grad for p in model.margin.expert.parameters())
        if cfg.get("train", True) and model.margin_cfg.lambda_dm > 0:  # the epoch's guidance activity, step = epoch
            assert [epoch for epoch, _, _ in model.margin_history] == [0]
            assert 0.0 <= model.margin_history[0][1] <= 1.0


def test_every_row_composes_validates_and_instantiates(spade_home: Path, tiny_checkpoints: dict) -> None:
    """Every row of every table: its config passes the checks of spade.train, and its data module, model (with
    the student's size, the margin's expert kind, a pretrained student) and trainer are built."""
    from spade.config.preflight import validate_train_config

    sizes = {"small": 1e5, "medium": 1e6, "large": 3e7}
    for row in ROWS:
        cfg = compose_row(row, spade_home)
        cfg = compose_row(row, spade_home, "logger=none", *_fill_requirements(cfg, tiny_checkpoints))
        validate_train_config(cfg)
        hydra.utils.instantiate(cfg.data)
        model = hydra.utils.instantiate(cfg.model)
        hydra.utils.instantiate(cfg.trainer)
        if cfg.model.get("size"):
            assert sum(p.numel() for p in model.net.parameters()) > sizes[cfg.model.size], row
        if cfg.model.get("margin"):
            model.load_margin((cfg.scale.image_size, cfg.scale.image_size))
            assert model.margin.conditional == (cfg.model.margin.expert == "conditional"), row
        assert cfg.tags.row == row and cfg.tags.table in ("table1", "table2", "table3"), row


def test_scale_presets_compose(spade_home: Path) -> None:
    for scale in ("tiny", "cpu", "paper"):
        cfg = compose_row("t1_medium_conddbc_L", spade_home, f"scale={scale}")
        dm = hydra.utils.instantiate(cfg.data)
        assert dm.batch_size == cfg.scale.batch_size
    cfg = compose_row("uncond_expert_U", spade_home, "scale=paper")
    with torch.device("meta"):
        model = hydra.utils.instantiate(cfg.model)
    assert sum(p.numel() for p in model.net.parameters()) > 9e8


def test_every_data_config_builds_a_missing_dataset_with_the_annotation_tool(tmp_path: Path) -> None:
    """The data module receives what builds a missing dataset from its config (conf/data/generator/annotate.yaml);
    without one it refuses a missing dataset rather than guessing."""
    from spade.annotation.run import generate_dataset
    from spade.data import DatasetError
    from spade.data.datamodule import PathDataModule
    from spade.utils.config import compose_config

    for data in sorted(p.stem for p in (CONF_DIR / "data").glob("*.yaml")):
        dm = hydra.utils.instantiate(compose_config("train", [f"data={data}"]).data)
        assert dm.generator.func is generate_dataset, data
    with pytest.raises(DatasetError, match="no generator"):
        PathDataModule(tmp_path / "missing", train_generate={"preset": "lshape"}).prepare_data()
    assert not (tmp_path / "missing").exists()


# -- a table is rows x seeds in one multirun, at scale=cpu unless told, announced at its start ---------
def _table_config(table: str, home: Path, *overrides: str):
    """The table's composition as `python -m spade.train +experiment=TABLE ...` sees it (no scale forced)."""
    import spade.experiments.multirun  # noqa: F401  (registers ${spade_sweep:}, as the table's Hydra callback does)
    from spade.utils.config import compose_config

    return compose_config("train", [f"+experiment={table}", f"paths.root_dir={home}", *overrides],
                          return_hydra_config=True)


def _jobs(cfg) -> list[list[str]]:
    """The job overrides Hydra's basic sweeper launches for ``cfg`` (its params, then the command line's)."""
    from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
    from hydra.core.override_parser.overrides_parser import OverridesParser

    params = [f"{k}={v}" for k, v in cfg.hydra.sweeper.params.items()]
    overrides = OverridesParser.create().parse_overrides([*params, *cfg.hydra.overrides.task])
    return [job for batch in BasicSweeper.split_arguments(overrides, None) for job in batch]


@pytest.mark.parametrize("table,count", sorted(TABLES.items()))
def test_seed_list_composes_into_rows_times_seeds(table: str, count: int, spade_home: Path) -> None:
    cfg = _table_config(table, spade_home)
    assert list(cfg.seeds) == [42, 1, 2] and cfg.scale.name == "cpu"  # the defaults: 3 seeds at scale=cpu
    assert cfg.hydra.sweeper.params.seed == "42,1,2" and cfg.hydra.sweeper.params.scale == "cpu"
    jobs = _jobs(cfg)
    assert len(jobs) == 3 * count
    first_row = cfg.hydra.sweeper.params.experiment.split(",")[0]
    assert [j[:3] for j in jobs[:3]] == [[f"experiment={first_row}", f"seed={s}", "scale=cpu"] for s in (42, 1, 2)]
    chosen = _table_config(table, spade_home, "seeds=[7,8]", "scale=tiny")
    jobs = _jobs(chosen)
    assert len(jobs) == 2 * count and {j[1] for j in jobs} == {"seed=7", "seed=8"}
    assert all("scale=tiny" in j for j in jobs)  # the command line's scale reaches every job
    one = _jobs(_table_config(table, spade_home, "seed=5"))
    assert len(one) == count and all("seed=5" in j for j in one)


def test_rows_select_a_subset_of_a_table_by_name_or_pattern(spade_home: Path) -> None:
    """`rows=` runs part of a table (Hydra refuses `hydra.sweeper.params.experiment=` on the command line)."""
    cfg = _table_config("table1", spade_home, "rows=[t1_small_*_L,cond_expert_L]", "seeds=[42,1]")
    jobs = _jobs(cfg)
    assert [j[0] for j in jobs] == [f"experiment={r}" for r in ("cond_expert_L", "t1_small_bc_L", "t1_small_dbc_L",
                                                               "t1_small_conddbc_L") for _ in (42, 1)]  # table order
    one = _jobs(_table_config("ablation_scratch", spade_home, "rows=[t3_bc_scratch_U]"))
    assert [j[:2] for j in one] == [["experiment=t3_bc_scratch_U", f"seed={s}"] for s in (42, 1, 2)]
    everything = _table_config("ablation_finetune", spade_home)
    assert everything.hydra.sweeper.params.experiment.split(",") == [
        "t2_bc_finetune_U", "t2_augbc_finetune_bc_U", "t2_augbc_finetune_conddbc_U"]


def test_row_selection_is_checked() -> None:
    from spade.experiments.multirun import row_sweep

    table = ("t1_small_bc_L", "t1_small_bc_U", "t1_medium_bc_L")
    assert row_sweep(None, *table) == ",".join(table)
    assert row_sweep(["*_L"], *table) == "t1_small_bc_L,t1_medium_bc_L"
    assert row_sweep("t1_small_bc_U", *table) == "t1_small_bc_U"
    with pytest.raises(ValueError, match=r"match no row of this table; its rows: t1_small_bc_L, t1_small_bc_U"):
        row_sweep(["t1_tiny_*"], *table)
    with pytest.raises(ValueError, match="selects no row"):
        row_sweep([], *table)


def test_seed_list_is_checked() -> None:
    from spade.experiments.multirun import seed_sweep

    assert seed_sweep([42, 1, 2]) == "42,1,2" and seed_sweep(7) == "7"
    for bad in ([], [1, 1], ["a"]):
        with pytest.raises(ValueError, match="seed"):
            seed_sweep(bad)


def test_a_bad_row_or_seed_list_ends_the_table_with_one_error_line(spade_home: Path, capsys,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """The table's start callback resolves the sweep before Hydra's sweeper would print OmegaConf's traceback."""
    from omegaconf.errors import InterpolationResolutionError

    from spade.experiments.multirun import TableStart

    monkeypatch.delenv("HYDRA_FULL_ERROR", raising=False)
    for override, message in (("seeds=[1,1]", "error: seeds=[1, 1] repeats a seed; each seed runs each row once"),
                              ("rows=[t9_*]", "error: rows=['t9_*'] match no row of this table; its rows: "
                                              "t2_bc_finetune_U, t2_augbc_finetune_bc_U")):
        config = _table_config("ablation_finetune", spade_home, override)
        with pytest.raises(SystemExit) as stop:
            TableStart().on_multirun_start(config)
        assert stop.value.code == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith(message) and len(err.splitlines()) == 1, err
    monkeypatch.setenv("HYDRA_FULL_ERROR", "1")
    with pytest.raises(InterpolationResolutionError, match="repeats a seed"):
        TableStart().on_multirun_start(_table_config("ablation_finetune", spade_home, "seeds=[1,1]"))


def test_table_prints_scale_rows_seeds_instances_and_estimate(spade_home: Path) -> None:
    from spade.experiments.multirun import STEP_SECONDS, estimate_row, start_message
    from spade.tracking.tables import TINY_NOTICE

    text = start_message(_table_config("ablation_scratch", spade_home))
    assert text.startswith("SPADE table run: scale=cpu, 2 rows x 3 seed(s) (42, 1, 2) = 6 runs")
    assert "rows: t3_bc_scratch_U, t3_augbc_pretrained_expert_U" in text
    assert "instances: 1,000 training, 15 % of it validation in" in text and "instances: 1,000 test in" in text
    assert "prerequisites to train first, once for all seeds" in text and "cond_expert_L" in text
    assert "estimated wall time: about" in text and TINY_NOTICE not in text
    # The cost model, by hand: ceil(1000 * 0.85 / 32) = 27 steps, 6 epochs, a medium BC step.
    row = compose_row("t3_bc_scratch_U", spade_home, "scale=cpu")
    cost = estimate_row(row)
    n_train = row.data.train_generate.set[-1].num_instances
    steps = -(-int(n_train * (1 - row.data.val_fraction)) // row.data.batch_size)
    assert (cost.kind, cost.steps_per_epoch, cost.epochs) == ("bc/medium", steps, row.trainer.max_epochs)
    assert cost.seconds > steps * row.trainer.max_epochs * STEP_SECONDS["bc/medium"]
    tiny = start_message(_table_config("ablation_scratch", spade_home, "scale=tiny", "seeds=[1]"))
    assert "scale=tiny, 2 rows x 1 seed(s) (1) = 2 runs" in tiny and TINY_NOTICE in tiny


def test_table_estimate_scales_with_the_speed_measured_on_this_machine(spade_home: Path) -> None:
    import math

    from spade.experiments.multirun import machine_speed, plan_table, start_message

    config = _table_config("ablation_scratch", spade_home)
    base, slow = plan_table(config), plan_table(config, speed=2.5)
    assert slow["total"] == pytest.approx(2.5 * base["total"])
    assert all(slow["costs"][r].seconds == pytest.approx(2.5 * base["costs"][r].seconds) for r in base["costs"])
    assert [c.seconds for c in slow["pending"].values()] == pytest.approx([2.5 * c.seconds for c in base["pending"].values()])
    for bad in (0.0, -1.0, math.nan, math.inf):
        with pytest.raises(ValueError, match="positive factor"):
            plan_table(config, speed=bad)
    assert "not measured here" in start_message(config)
    from spade.experiments.multirun import STEP_SECONDS

    reference = f"{STEP_SECONDS['bc/medium']:.2f}"  # the measured cost model (spade/experiments/cost_model.json)
    assert f"on this machine, which took 2.50 x the cost model's {reference} s for a medium BC step" in \
        start_message(config, 2.5)
    speed = machine_speed(runs=1)  # a real medium BC step here, against the reference machine's
    assert math.isfinite(speed) and 0.05 < speed < 100


def test_tiny_run_summary_says_pipeline_check(spade_home: Path) -> None:
    from spade.tracking.tables import TINY_NOTICE
    from spade.tracking.summary import run_summary

    metrics = {"test/ape_cm": 12.0}
    assert TINY_NOTICE in run_summary(compose_row("smoke", spade_home, "logger=none"), metrics)
    assert TINY_NOTICE not in run_summary(compose_row("smoke", spade_home, "logger=none", "scale=cpu"), metrics)


@pytest.mark.slow  # trains a whole table (2 rows x 2 seeds and its expert) at tiny scale, a few minutes
def test_table_runs_every_seed_and_trains_its_prerequisite_once(tmp_path: Path) -> None:
    import os
    import subprocess
    import sys

    from mlflow import MlflowClient

    from spade.experiments.reporting import build_report
    from spade.tracking.tables import TABLES, TINY_NOTICE

    env = {**os.environ, "SPADE_HOME": str(tmp_path), "PYTHONUNBUFFERED": "1", "OMP_NUM_THREADS": "1"}
    env.pop("MLFLOW_TRACKING_URI", None)
    args = ["+experiment=ablation_scratch", "scale=tiny", "seeds=[1,2]", "trainer.max_epochs=1",
            "++trainer.limit_train_batches=2", "++trainer.limit_val_batches=1", "++trainer.num_sanity_val_steps=0",
            "trainer.enable_progress_bar=false"]
    proc = subprocess.run([sys.executable, "-m", "spade.train", *args], cwd=CONF_DIR.parent, env=env,
                          capture_output=True, text=True, timeout=1500)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-4000:]
    assert "SPADE table run: scale=tiny, 2 rows x 2 seed(s) (1, 2) = 4 runs" in out
    assert out.index("SPADE table run") < out.index("Launching 4 jobs")  # printed before the first job
    assert out.count("run t3_") == 4 and out.count(TINY_NOTICE) >= 5  # start message + every run's summary
    uri = f"sqlite:///{tmp_path}/logs/mlflow.db"
    rep = build_report(TABLES["table3"], uri)
    assert all(r.n == 2 and r.seeds == [1, 2] for r in rep.results.values())
    assert TINY_NOTICE in rep.text
    client = MlflowClient(tracking_uri=uri)
    experts = [m for m in client.search_registered_models() if m.name.startswith("spade-cond_expert-L")]
    assert len(experts) == 1 and len(client.search_model_versions(f"name='{experts[0].name}'")) == 1


@pytest.mark.parametrize("row", ["g_few_bc_L", "g_few_conddbc_L", "g_few_conddbcst_L", "g_full_conddbcst_L"])
def test_guidance_rows_differ_only_in_the_margin_and_test_on_real_maps_too(row: str, spade_home: Path) -> None:
    cfg = compose_row(row, spade_home, "scale=quickstart")
    assert cfg.tags.table == "guidance" and cfg.run_name == row and cfg.model.size == "medium"
    assert dict(cfg.also_test) == {"real": "realmap_L"}
    assert cfg.data.get("max_train_instances") == (250 if "_few_" in row else None)
    margin = cfg.model.margin
    if row.endswith("_bc_L"):
        assert not margin
    else:
        assert margin.lambda_dm == 0.3 and margin.expert_ckpt.endswith("cond_expert_L_cpu_lite_x0.ckpt")
        assert margin.agent_input == ("straight_through" if "conddbcst" in row else "probability")


def test_guidance_composition_launches_its_six_rows(spade_home: Path) -> None:
    cfg = compose_row("guidance", spade_home, hydra_config=True)
    rows = cfg.hydra.sweeper.params.experiment.split(",")
    assert sorted(rows) == sorted(f"g_{r}_{a}_L" for r in ("few", "full") for a in ("bc", "conddbc", "conddbcst"))
    assert list(cfg.seeds) == [42, 1, 2, 3, 4]


def test_run_summary_says_when_a_student_did_not_learn_and_how_to_use_its_checkpoint(spade_home: Path) -> None:
    """A student that extracted nothing (failures 100 %) or lost to the heading template was reported
    like any other; the end of a run did not name the checkpoint that evaluate, export and plan need."""
    from spade.tracking.summary import run_summary

    cfg = compose_row("t1_small_bc_L", spade_home, "logger=none")
    # the verdict names its figure (the planner's APE and tail) and judges every baseline
    nothing = {"test/failure_rate": 1.0, "test/ape_cm": float("nan"), "test/baseline/heading/ape_cm": 10.5}
    losing = {"test/failure_rate": 0.0, "test/planner/ape_cm": 12.0, "test/planner/over_20cm_rate": 0.1,
              "test/baseline/heading/planner/ape_cm": 10.5, "test/baseline/heading/planner/over_20cm_rate": 0.05,
              "test/baseline/straight/planner/ape_cm": 20.5, "test/baseline/straight/planner/over_20cm_rate": 0.5}
    winning = {**losing, "test/planner/ape_cm": 5.0, "test/planner/over_20cm_rate": 0.0}
    assert "has not learned yet" in run_summary(cfg, nothing)
    lost = run_summary(cfg, losing)
    assert "the student loses to the heading template by the planner's APE and tail (12.00 vs 10.50 cm" in lost
    assert "the student beats the straight line" in lost and "deciding figure" in lost
    text = run_summary(cfg, winning, checkpoint="/runs/x/checkpoints/epoch004.ckpt")
    assert "loses" not in text and "beats the heading template" in text
    assert "best checkpoint  : /runs/x/checkpoints/epoch004.ckpt" in text
    assert "python -m spade.evaluate ckpt_path=/runs/x/checkpoints/epoch004.ckpt scale=" in text
    # one spade.plan syntax, the README's, with the checkpoint: it works from any folder (a runs:/ URI needs the store)
    assert "python -m spade.plan MAP.yaml start=X,Y,YAW goal=X,Y model=/runs/x/checkpoints/epoch004.ckpt" in text
    assert text.count("spade.plan") == 1
    own = compose_row("t1_small_bc_L", spade_home, "logger=none", "data=own", "data.train_dir=/d/site_train",
                      "data.test_dir=/d/site_test")
    pasted = " ".join(run_summary(own, winning, checkpoint="/c.ckpt").replace(" \\\n", " ").split())  # as pasted
    assert "spade.evaluate ckpt_path=/c.ckpt data=own data.train_dir=/d/site_train data.test_dir=/d/site_test" in pasted


def test_the_evaluate_command_names_a_rows_data_config(spade_home: Path, monkeypatch) -> None:
    """A sizing row's data (``onemap_L``) is set by its experiment file, not the command line: the printed evaluate
    command must name it, or spade.evaluate tests the checkpoint on its default data (lshape)."""
    from types import SimpleNamespace

    from hydra.core.hydra_config import HydraConfig

    from spade.tracking.summary import run_summary

    cfg = compose_row("sz_n300_e3_L", spade_home, "logger=none")
    monkeypatch.setattr(HydraConfig, "initialized", staticmethod(lambda: True))
    monkeypatch.setattr(HydraConfig, "get", staticmethod(lambda: SimpleNamespace(
        runtime=SimpleNamespace(choices={"data": "onemap_L"}), overrides=SimpleNamespace(task=[]))))
    text = run_summary(cfg, {"test/ape_cm": 5.0}, checkpoint="/c.ckpt")
    assert "python -m spade.evaluate ckpt_path=/c.ckpt data=onemap_L scale=" in text


def test_runs_on_own_data_log_to_their_own_experiment_never_a_paper_tables(spade_home: Path) -> None:
    """A run on a user's own datasets went into ``table1`` and ``spade.report table=table1`` listed it as
    a paper row. ``data=own`` (no generator) logs to ``own_<training folder>``."""
    from spade.tracking.tables import get_table

    paper = compose_row("t1_small_bc_L", spade_home)
    own = compose_row("t1_small_bc_L", spade_home, "data=own", "data.train_dir=/d/site_train",
                      "data.test_dir=/d/site_test")
    assert paper.logger.mlflow.experiment_name == get_table("table1").experiment
    assert own.logger.mlflow.experiment_name == "own_site_train"
    assert own.data.train_generate is None and own.data.test_generate is None


def test_the_regenerate_command_keeps_the_runs_data_and_seed(spade_home: Path, monkeypatch) -> None:
    """One run's MLflow description gave a "regenerate" command without its data overrides (it would
    train on procedural maps). The command keeps the command line's overrides, the seed, and drops a sweep's keys."""
    from types import SimpleNamespace

    from hydra.core.hydra_config import HydraConfig

    from spade.tracking.descriptions import regenerate_command

    task = ["+experiment=t1_small_bc_L", "scale=quickstart", "data=own", "data.train_dir=/d/train",
            "data.test_dir=/d/test", "seed=3", "rows=[t1_small_bc_L]"]
    monkeypatch.setattr(HydraConfig, "initialized", staticmethod(lambda: True))
    monkeypatch.setattr(HydraConfig, "get", staticmethod(lambda: SimpleNamespace(overrides=SimpleNamespace(task=task))))
    cfg = compose_row("t1_small_bc_L", spade_home, "scale=quickstart", "data=own", "data.train_dir=/d/train",
                      "data.test_dir=/d/test", "seed=3")
    command = regenerate_command(cfg)
    assert command == ("python -m spade.train +experiment=t1_small_bc_L scale=quickstart seed=3 "
                       "data=own data.train_dir=/d/train data.test_dir=/d/test")
    # Run as a command line, it composes the same run: the same data (so the same dataset fingerprint), model,
    # recipe and seed.
    from omegaconf import OmegaConf

    args = command.split()[3:]
    again = compose_row(args[0].split("=", 1)[1], spade_home, *args[1:])
    assert again.seed == cfg.seed
    for key in ("data", "model", "recipe", "scale", "trainer"):
        assert OmegaConf.to_container(again[key], resolve=True) == OmegaConf.to_container(cfg[key], resolve=True), key


# -- recipes apart from budgets: scale= sizes a run, recipe= holds the method --------------------------
SCALE_KEYS = {"name", "image_size", "resolution_m", "annotate", "train_instances", "test_instances",
              "transfer_instances", "train_maps", "max_epochs", "expert_max_epochs", "batch_size", "cond_expert_preset",
              "uncond_expert_preset", "ema_decay", "ddim_steps", "val_metric_batches", "critic_instances",
              "test_alternatives", "closed_loop",
              "defaults"}


def test_scales_hold_only_sizes_and_budgets() -> None:
    import yaml

    from spade.paths import CONF_DIR

    for path in sorted((Path(CONF_DIR) / "scale").glob("*.yaml")):
        extra = set(yaml.safe_load(path.read_text())) - SCALE_KEYS
        assert not extra, f"{path.name} sets method knobs {sorted(extra)}: they belong in conf/recipe"


def _method(cfg) -> dict:
    """What a student row trains with, apart from sizes and budgets."""
    from omegaconf import OmegaConf

    model = OmegaConf.to_container(cfg.model, resolve=True)
    return {"bc_pos_weight": model["bc_pos_weight"], "optimizer": model["optimizer"],
            "lr_scheduler": model["lr_scheduler"], "margin": {**model["margin"], "expert_ckpt": None},
            "target_width_px": cfg.data.target_width_px, "augment": cfg.data.augment}


def test_a_row_is_the_same_method_at_every_scale_and_the_recipe_changes_it(tmp_path) -> None:
    from spade.utils.config import compose_config

    def row(*overrides):
        return compose_config("train", ["+experiment=t1_medium_conddbc_L", f"paths.root_dir={tmp_path}", *overrides])

    cpu, paper, tiny = row("scale=cpu"), row("scale=paper"), row("scale=tiny")
    assert _method(cpu) == _method(paper) == _method(tiny)
    assert cpu.model.margin.lambda_dm == cpu.recipe.lambda_dm
    quick = compose_config("train", ["+experiment=quickstart", f"paths.root_dir={tmp_path}"])
    assert _method(quick) == _method(cpu)  # the quickstart is Table 1's row, smaller
    paper_recipe = row("scale=cpu", "recipe=paper")
    assert paper_recipe.model.bc_pos_weight is None and paper_recipe.data.target_width_px == 1
    assert _method(paper_recipe) != _method(cpu)
    expert = compose_config("train", ["+experiment=cond_expert_L", "recipe=paper", f"paths.root_dir={tmp_path}"])
    assert expert.model.prediction_type == "epsilon" and expert.model.optimizer.lr == 1e-4


def test_cfg_job_shows_the_method_and_lambda(tmp_path) -> None:
    import os
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-m", "spade.train", "+experiment=t1_medium_conddbc_L", "scale=cpu",
                          "--cfg", "job", "--resolve"], capture_output=True, text=True, cwd=tmp_path,
                         env={**os.environ, "SPADE_HOME": str(tmp_path)}, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    import yaml

    job = yaml.safe_load(out.stdout)
    assert job["recipe"]["name"] == "spade" and job["model"]["margin"]["lambda_dm"] == job["recipe"]["lambda_dm"]
    assert job["model"]["bc_pos_weight"] == job["recipe"]["bc_pos_weight"]
    assert job["requires"]["expert"]["experiment"] == "cond_expert_L"


@pytest.mark.parametrize("old,new", [("expert_cond_L", "cond_expert_L"), ("expert_uncond_U", "uncond_expert_U")])
def test_an_experts_old_name_composes_the_new_row_and_says_so(old: str, new: str, tmp_path) -> None:
    """One name per expert (cond_expert / uncond_expert, docs/reference/glossary.md); the old experiment names
    compose the same row for one release and carry the rename for spade.train's warning."""
    from omegaconf import OmegaConf

    from spade.utils.config import compose_config

    def compose(name):
        return compose_config("train", [f"+experiment={name}", f"paths.root_dir={tmp_path}"])

    aliased, current = compose(old), compose(new)
    assert aliased.deprecated_experiment.old == old and aliased.deprecated_experiment.new == new
    with_alias = OmegaConf.to_container(aliased, resolve=False)
    with_alias.pop("deprecated_experiment")
    assert with_alias == OmegaConf.to_container(current, resolve=False)
    assert current.run_name == new
