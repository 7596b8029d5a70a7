"""spade.experiments.reporting (`python -m spade.report`) and spade.tracking.tables: layouts match the
experiments, missing rows stay, arithmetic holds."""

from __future__ import annotations

import csv
import time
from pathlib import Path

import pytest
import yaml

from spade.tracking.tables import TABLES, get_table, relative_change
from spade.paths import CONF_DIR
from spade.experiments.reporting import build_report, compare, fetch_results, render_table
from spade.experiments.reporting.pages import report

# The paper's rows behind its headline (DESIGN.md section 6): medium Cond-DBC and large BC, L-shape.
MEDIUM_CONDDBC_L = {"test/ape_cm": 1.46, "test/fid": 13.58, "test/hd19": 2.0, "model/params": 1_926_209.0}
LARGE_BC_L = {"test/ape_cm": 2.41, "test/fid": 20.45, "test/hd19": 5.0, "model/params": 31_114_785.0}


def _experiment_yaml(name: str) -> dict:
    return yaml.safe_load((CONF_DIR / "experiment" / f"{name}.yaml").read_text())


@pytest.mark.parametrize("key", sorted(TABLES))
def test_table_layouts_match_the_experiment_configs(key: str) -> None:
    table = TABLES[key]
    for row in table.experiments:
        cfg = _experiment_yaml(row)
        assert cfg["run_name"] == row and cfg["tags"]["table"] == table.experiment, row
    from omegaconf import OmegaConf

    import spade.experiments.multirun  # noqa: F401  (registers ${spade_rows:})

    sweep = _experiment_yaml(table.composition)["hydra"]["sweeper"]["params"]["experiment"]
    launched = OmegaConf.create({"rows": None, "experiment": sweep}).experiment.split(",")  # rows=null: all
    assert sorted(launched) == sorted(table.experiments)
    for column in table.tested_elsewhere:  # another test of a row's checkpoint: the row asks for it (also_test)
        for line in table.lines:
            base = line.cells[table.shapes[0]]
            assert line.cells[column] == f"{base}_{column}"
            assert column in yaml.safe_load((CONF_DIR / "experiment" / "g_base.yaml").read_text())["also_test"]
    for comp in table.comparisons:
        assert {comp.row, comp.baseline} <= set(table.rows)


def test_every_row_of_the_paper_is_in_a_table() -> None:
    rows = {p.stem for p in (CONF_DIR / "experiment").glob("*.yaml") if p.stem.startswith(("t1_", "t2_", "t3_", "cond_expert_", "uncond_expert_"))}
    paper = {r for t in TABLES.values() if t.key in ("table1", "table2", "table3") for r in t.rows}
    assert rows == paper and len(rows) == 27


def test_get_table_accepts_aliases_and_names_the_choices() -> None:
    assert get_table("2") is get_table("ablation_finetune") is TABLES["table2"]
    with pytest.raises(ValueError, match="table1, table2, table3"):
        get_table("table4")


def test_relative_change_against_hand_computed_values() -> None:
    assert relative_change(1.46, 2.41) == pytest.approx(-39.4190871, abs=1e-6)  # (1.46 - 2.41) / 2.41
    assert relative_change(1_926_209, 31_114_785) == pytest.approx(-93.8093, abs=1e-4)
    assert relative_change(3.0, 2.0) == pytest.approx(50.0)
    assert relative_change(1.0, 0.0) is None and relative_change(None, 1.0) is None
    assert relative_change(float("nan"), 1.0) is None


def _log_run(client, experiment_id: str, name: str, metrics: dict[str, float], status: str = "FINISHED",
             scale: str = "tiny", seed: int | None = None) -> str:
    run = client.create_run(experiment_id, run_name=name, tags={"scale": scale, "row": name})
    if seed is not None:
        client.log_param(run.info.run_id, "cfg/seed", seed)  # as spade.train logs the composed config
    for key, value in metrics.items():
        client.log_metric(run.info.run_id, key, value)
    if status != "RUNNING":
        client.set_terminated(run.info.run_id, status=status)
    time.sleep(0.01)  # distinct end times
    return run.info.run_id


@pytest.fixture(scope="module")
def store(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """An MLflow store holding part of Table 1 and two of Table 2's three rows (one of them run three times)."""
    from mlflow import MlflowClient

    uri = f"sqlite:///{tmp_path_factory.mktemp('mlflow')}/mlflow.db"
    client = MlflowClient(tracking_uri=uri)
    t1 = client.create_experiment("table1")
    _log_run(client, t1, "t1_medium_conddbc_L", MEDIUM_CONDDBC_L)
    _log_run(client, t1, "t1_large_bc_L", LARGE_BC_L)
    _log_run(client, t1, "t1_large_bc_U", {**LARGE_BC_L, "test/hd19": 0.0})
    _log_run(client, t1, "t1_medium_conddbc_U", MEDIUM_CONDDBC_L)
    _log_run(client, t1, "t1_small_bc_L", {"test/ape_cm": 9.0}, scale="cpu")
    t2 = client.create_experiment("table2")
    _log_run(client, t2, "t2_bc_finetune_U", {"test/ape_cm": 8.0, "test/hd19": 10.0})
    latest = _log_run(client, t2, "t2_bc_finetune_U", {"test/ape_cm": 6.0, "test/hd19": 4.0})
    _log_run(client, t2, "t2_bc_finetune_U", {}, status="FAILED")
    _log_run(client, t2, "t2_augbc_finetune_conddbc_U", {"test/ape_cm": 4.5, "test/hd19": 3.0})
    _log_run(client, t2, "t2_augbc_finetune_bc_U", {"test/ape_cm": 1.0}, status="RUNNING")
    return {"uri": uri, "latest": latest}


def test_missing_rows_are_shown_never_dropped(store: dict) -> None:
    table = TABLES["table2"]
    rep = build_report(table, store["uri"])
    lines = [ln for ln in render_table(table, rep.results).splitlines()[2:]]
    assert len(lines) == 3
    unfinished = next(ln for ln in lines if "Aug. BC, fine-tuned (BC)" in ln)
    assert "missing" in unfinished
    assert "t2_augbc_finetune_bc_U: missing, 1 run(s), none finished (RUNNING)" in rep.text
    assert "2 of 3 rows have a finished run" in rep.text
    empty = build_report(TABLES["table3"], store["uri"])  # no MLflow experiment at all
    assert empty.text.count("| missing |") == 2
    assert "missing, no run: t3_bc_scratch_U, t3_augbc_pretrained_expert_U" in empty.text


def test_latest_finished_run_is_used_and_counted(store: dict) -> None:
    results = fetch_results(TABLES["table2"], store["uri"])
    row = results["t2_bc_finetune_U"]
    assert row.run_id == store["latest"] and (row.n_runs, row.n_finished) == (3, 2)
    assert row.value("ape_cm") == 6.0 and row.value("fid") is None
    text = build_report(TABLES["table2"], store["uri"]).text
    assert f"t2_bc_finetune_U: 3 runs (2 finished); using the latest finished, run {store['latest']}" in text
    assert "| 6.00 / 4 |" not in text and "n/a / 6.00 / 4" in text


def test_headline_comparison_arithmetic(store: dict) -> None:
    table = TABLES["table1"]
    changes = {(c.title, c.metric): c for c in compare(table, fetch_results(table, store["uri"]))}
    head = "medium Cond-DBC vs large BC (L)"
    assert changes[head, "ape_cm"].change == pytest.approx(100 * (1.46 - 2.41) / 2.41)
    assert changes[head, "fid"].change == pytest.approx(100 * (13.58 - 20.45) / 20.45)  # -33.59
    assert changes[head, "hd19"].change == pytest.approx(-60.0)
    assert changes[head, "params"].change == pytest.approx(100 * (1_926_209 - 31_114_785) / 31_114_785)
    assert changes[head, "ape_cm"].paper == -39.1 and changes[head, "params"].paper == -93.8
    assert changes["medium Cond-DBC vs large BC (U)", "hd19"].change is None  # baseline Hd19 is 0
    text = build_report(table, store["uri"]).text
    assert "-39.4%" in text and "n/a (baseline 0)" in text


def test_scale_filter_and_mixed_scale_note(store: dict) -> None:
    table = TABLES["table1"]
    assert "different scales (cpu, tiny)" in build_report(table, store["uri"]).text
    assert not fetch_results(table, store["uri"], scale="tiny")["t1_small_bc_L"].found


def test_cli_config_writes_markdown_csv_and_png(store: dict, tmp_path: Path) -> None:
    from PIL import Image

    from spade.utils.config import compose_config

    cfg = compose_config("report", ["table=ablation_finetune", f"tracking_uri={store['uri']}",
                                    f"output_dir={tmp_path}", "paths.output_dir=."])
    (rep,) = report(cfg)
    assert set(rep.files) == {"csv", "comparisons_csv", "png", "markdown"}
    with open(rep.files["csv"]) as fh:
        rows = list(csv.DictReader(fh))
    assert [r["row"] for r in rows] == TABLES["table2"].rows
    assert [r["status"] for r in rows] == ["ok", "missing", "ok"]
    assert float(rows[0]["ape_cm"]) == 6.0 and rows[1]["ape_cm"] == "" and float(rows[0]["paper_ape_cm"]) == 7.75
    with open(rep.files["comparisons_csv"]) as fh:
        ape = next(r for r in csv.DictReader(fh) if r["metric"] == "ape_cm")
    assert float(ape["change_pct"]) == pytest.approx(100 * (4.5 - 6.0) / 6.0)
    with Image.open(rep.files["png"]) as im:
        assert im.size[0] > 300 and im.size[1] > 200
    assert rep.files["markdown"].read_text().startswith("# Table 2")


def test_cli_scale_override_filters_runs(store: dict, tmp_path: Path) -> None:
    """`scale=cpu` on the command line selects the conf/scale group, whose name filters the runs."""
    from spade.utils.config import compose_config

    overrides = ["table=table1", f"tracking_uri={store['uri']}", f"output_dir={tmp_path}", "paths.output_dir=.",
                 "chart=false", "overwrite=true"]  # three reports into one folder
    (everything,) = report(compose_config("report", overrides))
    (cpu,) = report(compose_config("report", [*overrides, "scale=cpu"]))
    (tiny,) = report(compose_config("report", [*overrides, "scale=tiny"]))
    assert everything.results["t1_small_bc_L"].found and cpu.results["t1_small_bc_L"].found
    assert not tiny.results["t1_small_bc_L"].found and "scale cpu" in cpu.text


def test_baselines_are_reference_rows_and_losing_rows_are_named(tmp_path: Path) -> None:
    """Every table shows the classical baselines of its test set, and says plainly which rows lose to them."""
    from mlflow import MlflowClient

    uri = f"sqlite:///{tmp_path}/mlflow.db"
    client = MlflowClient(tracking_uri=uri)
    t3 = client.create_experiment("table3")
    baselines = {"test/baseline/straight/ape_cm": 24.0, "test/baseline/straight/failure_rate": 0.0,
                 "test/baseline/shortest/ape_cm": 29.0, "test/baseline/heading/ape_cm": 12.5,
                 "test/baseline/heading/hd19": 3.0}
    # the deciding figure: the planner's APE and tail
    planners = {"test/baseline/straight/planner/ape_cm": 24.0, "test/baseline/shortest/planner/ape_cm": 29.0,
                "test/baseline/heading/planner/ape_cm": 12.5, "test/baseline/heading/planner/over_20cm_rate": 0.1}
    _log_run(client, t3, "t3_bc_scratch_U", {"test/ape_cm": 30.0, "test/failure_rate": 0.01, **baselines, **planners,
                                             "test/planner/ape_cm": 30.0, "test/planner/over_20cm_rate": 0.5})
    _log_run(client, t3, "t3_augbc_pretrained_expert_U", {"test/ape_cm": 6.0, "test/failure_rate": 0.005, **baselines,
                                                          **planners, "test/planner/ape_cm": 6.0,
                                                          "test/planner/over_20cm_rate": 0.05})
    rep = build_report(TABLES["table3"], uri)
    table = render_table(TABLES["table3"], rep.results)
    assert "reference: straight line | n/a / 24.00 / n/a / 0.0% / n/a / 24.00 / n/a | 0 (no learning)" in table
    assert "reference: heading template | n/a / 12.50 / 3 / n/a / n/a / 12.50 / 10.0% |" in table
    assert ("t3_bc_scratch_U LOSES to the straight line, shortest path (Nav2-like), heading template on its own test "
            "set by the deciding figure") in rep.text
    assert "t3_augbc_pretrained_expert_U LOSES" not in rep.text
    assert "Which figure decides: the planner's APE with its tail" in rep.text


# -- seeds: mean +/- sd per cell, Welch's t-test between compared rows -------------------------------------------
# Hand-computed: SKIPP BC APE 10, 12, 14 (mean 12, sd 2); Cond-DBC 6, 7, 8 (mean 7, sd 1). Welch: t = -5 /
# sqrt(4/3 + 1/3) = -3.873, df = (5/3)^2 / ((4/3)^2/2 + (1/3)^2/2) = 50/17 = 2.941, two-sided p = 0.03156.
# Hd19 30, 34, 32 (mean 32, sd 2) against 28, 33, 32 (mean 31, sd sqrt(7) = 2.6458): t = -0.522, df = 3.723,
# p = 0.6310 (not significant).
SKIPP = {42: (10.0, 30.0, 0.1), 1: (12.0, 34.0, 0.2), 2: (14.0, 32.0, 0.3)}
CONDDBC = {42: (6.0, 28.0, 0.0), 1: (7.0, 33.0, 0.0), 2: (8.0, 32.0, 0.0)}


def _cell_metrics(ape: float, hd19: float, failures: float) -> dict[str, float]:
    return {"test/ape_cm": ape, "test/hd19": hd19, "test/failure_rate": failures, "model/params": 1_926_209.0}


@pytest.fixture(scope="module")
def seeded(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """Table 2 with three seeds of two rows and one seed of the third, plus runs that must not count: an older run
    of a seed (replaced by its rerun), a FAILED run and a finished run at another scale."""
    from mlflow import MlflowClient

    uri = f"sqlite:///{tmp_path_factory.mktemp('seeded')}/mlflow.db"
    client = MlflowClient(tracking_uri=uri)
    t2 = client.create_experiment("table2")
    _log_run(client, t2, "t2_bc_finetune_U", _cell_metrics(50.0, 90.0, 0.9), scale="cpu", seed=42)
    _log_run(client, t2, "t2_bc_finetune_U", _cell_metrics(99.0, 99.0, 0.9), seed=42)  # rerun below replaces it
    for seed, figures in SKIPP.items():
        _log_run(client, t2, "t2_bc_finetune_U", _cell_metrics(*figures), seed=seed)
    _log_run(client, t2, "t2_bc_finetune_U", {}, status="FAILED", seed=3)
    for seed, figures in CONDDBC.items():
        _log_run(client, t2, "t2_augbc_finetune_conddbc_U", _cell_metrics(*figures), seed=seed)
    _log_run(client, t2, "t2_augbc_finetune_bc_U", _cell_metrics(9.0, 20.0, 0.05), seed=42)
    return {"uri": uri}


def test_rows_aggregate_their_seeds_mean_and_sd(seeded: dict) -> None:
    results = fetch_results(TABLES["table2"], seeded["uri"])
    skipp = results["t2_bc_finetune_U"]
    assert skipp.seeds == [1, 2, 42] and skipp.n == 3 and skipp.scale == "tiny"
    assert (skipp.n_runs, skipp.n_finished, skipp.n_other_scales) == (6, 5, 1)
    assert skipp.value("ape_cm") == pytest.approx(12.0) and skipp.sd("ape_cm") == pytest.approx(2.0)
    assert skipp.value("failure_rate") == pytest.approx(0.2) and skipp.sd("failure_rate") == pytest.approx(0.1)
    conddbc = results["t2_augbc_finetune_conddbc_U"]
    assert conddbc.value("hd19") == pytest.approx(31.0) and conddbc.sd("hd19") == pytest.approx(7 ** 0.5)
    one = results["t2_augbc_finetune_bc_U"]
    assert one.n == 1 and one.value("ape_cm") == 9.0 and one.sd("ape_cm") is None
    cpu = fetch_results(TABLES["table2"], seeded["uri"], scale="cpu")["t2_bc_finetune_U"]
    assert cpu.n == 1 and cpu.value("ape_cm") == 50.0  # scale= picks the other scale's runs alone


def test_comparison_uses_means_and_welch_test(seeded: dict) -> None:
    table = TABLES["table2"]
    changes = {c.metric: c for c in compare(table, fetch_results(table, seeded["uri"]))}
    ape, hd19 = changes["ape_cm"], changes["hd19"]
    assert ape.change == pytest.approx(100 * (7.0 - 12.0) / 12.0) and (ape.n, ape.baseline_n) == (3, 3)
    assert ape.p_value == pytest.approx(0.031562, abs=1e-5) and ape.significant is True
    assert hd19.p_value == pytest.approx(0.631028, abs=1e-5) and hd19.significant is False
    assert changes["fid"].p_value is None and changes["fid"].test == "no test (missing)"


def test_report_text_marks_seeds_sd_and_significance(seeded: dict, tmp_path: Path) -> None:
    rep = build_report(TABLES["table2"], seeded["uri"], tmp_path, chart=False)
    text = rep.text
    assert "12.00 ± 2.00" in text and "20.0 ± 10.0%" in text and "7.00 ± 1.00" in text
    skipp_line = next(ln for ln in text.splitlines() if ln.startswith("| SKIPP BC, fine-tuned (BC) |"))
    assert skipp_line.rstrip().endswith("| 3 |")  # the seeds column
    one_line = next(ln for ln in text.splitlines() if ln.startswith("| Aug. BC, fine-tuned (BC) |"))
    assert "9.00 /" in one_line and "±" not in one_line and one_line.rstrip().endswith("| 1 |")
    assert "-41.7%" in text and "p = 0.0316" in text
    assert "-3.1% (not significant)" in text and "p = 0.631, not significant" in text
    assert "n=1, no test" in text  # the pairwise tests against the one-seed row
    assert "Welch's t-test (two-sided, unequal variances, alpha 0.05)" in text
    assert "t2_bc_finetune_U: 3 seeds (1, 2, 42) at scale tiny, from 6 runs (5 finished)" in text
    assert "1 finished run(s) at other scales left out" in text
    with open(rep.files["csv"]) as fh:
        row = next(r for r in csv.DictReader(fh) if r["row"] == "t2_bc_finetune_U")
    assert float(row["ape_cm"]) == pytest.approx(12.0) and float(row["ape_cm_sd"]) == pytest.approx(2.0)
    assert row["n_seeds"] == "3" and row["seeds"] == "1 2 42" and len(row["run_ids"].split()) == 3
    with open(rep.files["comparisons_csv"]) as fh:
        rows = list(csv.DictReader(fh))
    ape = next(r for r in rows if r["kind"] == "headline" and r["metric"] == "ape_cm")
    assert float(ape["p_value"]) == pytest.approx(0.031562, abs=1e-5) and ape["significant"] == "True"
    assert float(ape["value"]) == pytest.approx(7.0) and float(ape["baseline_value"]) == pytest.approx(12.0)
    assert {r["test"] for r in rows if r["kind"] == "pairwise"} >= {"n=1, no test"}


def test_one_seed_says_no_test(store: dict) -> None:
    text = build_report(TABLES["table2"], store["uri"]).text
    assert "| n=1, no test |" in text and "% (not significant)" not in text and ", not significant |" not in text


def test_tiny_scale_report_says_pipeline_check(seeded: dict) -> None:
    from spade.tracking.tables import TINY_NOTICE

    assert TINY_NOTICE in build_report(TABLES["table2"], seeded["uri"]).text
    assert "pipeline check, not a result" in TINY_NOTICE
    assert TINY_NOTICE not in build_report(TABLES["table2"], seeded["uri"], scale="cpu").text


def test_holm_correction_against_hand_computed_values() -> None:
    from spade.experiments.reporting.stats import holm

    # sorted: 0.01 x 3 = 0.03; 0.03 x 2 = 0.06; 0.04 x 1 = 0.04 -> kept monotone at 0.06; None stays out
    assert holm([0.01, 0.04, None, 0.03]) == pytest.approx([0.03, 0.06, None, 0.06])
    assert holm([0.5, 0.9]) == pytest.approx([1.0, 1.0])
    assert holm([]) == []


def test_guidance_report_tests_pairs_with_holm_and_states_its_provenance(tmp_path: Path) -> None:
    """Three seeds of two guidance rows on the held-out map: the pairwise test is Welch's, Holm-corrected over the
    table's tests, and the page names its command, commit, date, machine and the runs' wall time."""
    from mlflow import MlflowClient

    uri = f"sqlite:///{tmp_path}/mlflow.db"
    client = MlflowClient(tracking_uri=uri)
    exp = client.create_experiment("guidance")
    for seed, (bc, st) in {1: (5.0, 4.0), 2: (5.2, 4.1), 3: (5.4, 4.2)}.items():
        _log_run(client, exp, "g_few_bc_L", _cell_metrics(bc, 0, 0), seed=seed)
        _log_run(client, exp, "g_few_conddbcst_L", _cell_metrics(st, 0, 0), seed=seed)
        _log_run(client, exp, "g_few_bc_L_real", _cell_metrics(bc + 1, 0, 0), seed=seed)
    rep = build_report(TABLES["guidance"], uri, tmp_path, chart=False)
    pair = next(c for c in rep.pairs if c.row == "g_few_conddbcst_L" and c.baseline == "g_few_bc_L")
    from scipy.stats import ttest_ind

    p = ttest_ind([4.0, 4.1, 4.2], [5.0, 5.2, 5.4], equal_var=False).pvalue
    assert pair.p_value == pytest.approx(p) and pair.p_holm == pytest.approx(min(1.0, p * sum(
        c.p_value is not None for c in rep.pairs)))
    assert rep.results["g_few_bc_L_real"].value("ape_cm") == pytest.approx(6.2)
    text = rep.text
    assert "Holm-corrected" in text and "- commit: " in text and "- machine: " in text and "wall time" in text
    assert "The paper's figures" not in text  # not a table of the paper


def test_a_cell_with_a_nan_seed_says_how_many_seeds_it_is_over() -> None:
    """A cell where one of two seeds logged NaN (no path extracted) showed the other seed's value as if
    it were the row's, with no spread and no count."""
    import math

    from spade.experiments.reporting.render import seed_cell
    from spade.experiments.reporting.results import RowResult, SeedRun
    from spade.tracking.tables import METRICS

    row = RowResult("r", runs=[SeedRun(1, "a", 1, {"ape_cm": 294.14}), SeedRun(2, "b", 2, {"ape_cm": math.nan})],
                    run_id="b")
    row.metrics = {"ape_cm": 294.14}
    assert seed_cell(METRICS["ape_cm"], row, "ape_cm").endswith("(1 of 2 seeds; NaN counted as failure)")
    whole = RowResult("r", runs=[SeedRun(1, "a", 1, {"ape_cm": 4.0}), SeedRun(2, "b", 2, {"ape_cm": 6.0})],
                      run_id="b", metrics={"ape_cm": 5.0})
    assert "of 2 seeds" not in seed_cell(METRICS["ape_cm"], whole, "ape_cm")


def test_a_rows_seeds_share_their_data_and_runs_on_other_data_are_left_out_and_said(tmp_path: Path) -> None:
    """A run on other datasets under a row's name (a user's own data, a regenerated dataset) is never
    averaged into the row's seeds; the report says how many were left out."""
    from mlflow import MlflowClient
    from mlflow.entities import Dataset, DatasetInput, InputTag

    uri = f"sqlite:///{tmp_path}/mlflow.db"
    client = MlflowClient(tracking_uri=uri)
    table = TABLES["table2"]
    exp = client.create_experiment(table.experiment)
    row = table.rows[0]

    def run_on(digest: str, seed: int, ape: float) -> str:
        run_id = _log_run(client, exp, row, {"test/ape_cm": ape}, scale="cpu", seed=seed)
        client.log_inputs(run_id, datasets=[DatasetInput(
            Dataset(name=f"cpu/{digest}", digest=digest, source_type="local", source=f"/data/{digest}"),
            tags=[InputTag(key="mlflow.data.context", value="test")])])
        return run_id

    run_on("aaaa", 1, 4.0)
    run_on("bbbb", 2, 40.0)  # another test set under the same row name
    run_on("aaaa", 3, 6.0)  # the latest: its data is the row's
    result = fetch_results(table, uri)[row]
    assert result.seeds == [1, 3] and result.n_other_data == 1
    assert result.value("ape_cm") == pytest.approx(5.0)
    assert f"{row}: 1 finished run(s) on other datasets left out" in build_report(table, uri).text


def test_pairwise_tests_the_deciding_figure_first_and_corrects_over_every_test(tmp_path: Path) -> None:
    """The pairwise tests compare the planner's APE (the deciding figure) first, then the paper's APE and
    the preference figures the runs logged; Holm's correction counts all of them."""
    from mlflow import MlflowClient

    uri = f"sqlite:///{tmp_path}/mlflow.db"
    client = MlflowClient(tracking_uri=uri)
    exp = client.create_experiment("encoding")
    for seed, (a, b) in {1: (4.0, 3.6), 2: (4.2, 3.7), 3: (4.1, 3.5)}.items():
        for row, v in (("enc_binary_L", a), ("enc_aa_disc_L", b)):
            _log_run(client, exp, row, {**_cell_metrics(v + 0.5, 0, 0), "test/planner/ape_cm": v,
                                        "test/planner/plausibility_cm": v / 2}, seed=seed)
    rep = build_report(TABLES["encoding"], uri, tmp_path, chart=False)
    metrics = [c.metric for c in rep.pairs]
    assert metrics == ["planner_ape_cm", "ape_cm", "planner_plausibility_cm"]  # commit rate: logged by no run
    tested = sum(c.p_value is not None for c in rep.pairs)
    assert all(c.p_holm == pytest.approx(min(1.0, c.p_value * tested)) or c.p_holm >= c.p_value for c in rep.pairs)
    assert "the deciding figure first" in rep.text


def test_the_page_renders_its_lists_and_shows_paths_relative_to_spade_home(tmp_path: Path,
                                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """The written page: notes and provenance as Markdown lists (a blank line before each), and the store and the
    files written named relative to SPADE_HOME, never by the writing machine's absolute path."""
    import markdown
    from mlflow import MlflowClient

    monkeypatch.setenv("SPADE_HOME", str(tmp_path))
    uri = f"sqlite:///{tmp_path}/mlflow.db"
    client = MlflowClient(tracking_uri=uri)
    exp = client.create_experiment("guidance")
    for seed in (1, 2):
        _log_run(client, exp, "g_few_bc_L", _cell_metrics(5.0 + seed, 0, 0), seed=seed)
    rep = build_report(TABLES["guidance"], uri, tmp_path / "reports", chart=False)
    page = rep.files["markdown"].read_text()
    assert str(tmp_path) not in page
    assert "MLflow experiment `guidance` in sqlite:///mlflow.db" in page
    assert "Written: reports/guidance.csv, " in page and "reports/guidance.md" in page
    assert "Notes:\n\n- " in page and "Provenance:\n\n- command: `python -m spade.report" in page
    html = markdown.markdown(page, extensions=["tables"])
    assert "<p>Notes:</p>\n<ul>" in html and "<p>Provenance:</p>\n<ul>" in html


# -- the statistics and page kernel ------------------------------------------------------------------------------
KERNEL = Path(__file__).resolve().parents[1] / "spade" / "experiments" / "reporting" / "stats.py"
KERNEL_FUNCTIONS = ("holm", "welch", "paired", "one_sample", "one_sample_p", "mean_sd", "markdown_table", "padded",
                    "collapsed", "provenance_lines", "significance")
"""The kernel's functions (spade.experiments.reporting.stats, spade.utils.markdown, spade.utils.provenance), under
any number of leading underscores: each may be defined once in spade/."""


def _spade_sources() -> list[tuple[Path, "ast.Module"]]:
    import ast

    package = KERNEL.parents[2]
    return [(p, ast.parse(p.read_text(), str(p))) for p in sorted(package.rglob("*.py"))]


def test_the_statistics_and_table_writers_are_defined_once() -> None:
    """Holm, Welch, the paired and one-sample tests, mean ± sd, the markdown table and the provenance block each
    have one definition in spade/; a page that needs one imports it."""
    import ast

    found: dict[str, list[str]] = {}
    for path, tree in _spade_sources():
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.name.lstrip("_") in KERNEL_FUNCTIONS:
                found.setdefault(node.name.lstrip("_"), []).append(f"{path.name}:{node.lineno}")
    twins = {name: where for name, where in found.items() if len(where) > 1}
    assert not twins, f"defined more than once (use the kernel's): {twins}"
    assert {"holm", "welch", "paired", "one_sample", "mean_sd", "markdown_table", "provenance_lines"} <= set(found)


def test_scipy_t_tests_are_called_in_the_kernel_alone() -> None:
    """Every t-test of a results page goes through spade.experiments.reporting.stats (its degenerate samples, its
    NaN p-values handled once): no other module names scipy.stats.ttest_*."""
    import ast

    outside = []
    for path, tree in _spade_sources():
        if path == KERNEL:
            continue
        for node in ast.walk(tree):
            names = [a.name for a in node.names] if isinstance(node, ast.ImportFrom) else []
            if isinstance(node, ast.Attribute):
                names.append(node.attr)
            outside += [f"{path.name}:{node.lineno} {n}" for n in names if n.startswith("ttest_")]
    assert not outside, f"scipy t-tests outside the kernel: {outside}"


def test_the_kernels_tests_agree_with_scipy_and_refuse_degenerate_samples() -> None:
    from scipy import stats as scipy_stats

    from spade.experiments.reporting.stats import NO_TEST, one_sample, paired, welch

    a, b = [4.0, 4.1, 4.3], [5.0, 5.2, 5.5]
    p, wording = welch(a, b)
    assert p == pytest.approx(scipy_stats.ttest_ind(a, b, equal_var=False).pvalue) and wording == f"p = {p:.3g}"
    assert welch([1.0], b) == (None, NO_TEST) and welch([1.0, 1.0], [2.0, 2.0]) == (None, "no test (no spread)")
    assert welch([1.0, 2.0], [1.0, 2.0])[1] == "p = 1, not significant"
    assert paired(a, b) == pytest.approx(scipy_stats.ttest_rel(a, b).pvalue)
    assert paired([1.0, 2.0], [0.0, 1.0]) is None and paired([1.0], [2.0]) is None  # constant differences, one pair
    assert one_sample(a, 5.0) == pytest.approx(scipy_stats.ttest_1samp(a, 5.0).pvalue)
    assert one_sample([3.0, 3.0], 5.0) is None and one_sample([3.0], 5.0) is None


def test_mean_sd_writes_the_sample_sd_and_the_value_alone_for_one_seed() -> None:
    from spade.experiments.reporting.stats import mean_sd, significance

    assert mean_sd([1.0, 2.0, 3.0]) == "2.00 ± 1.00"  # ddof=1
    assert mean_sd([0.5, 0.7], ".0%", lambda sd: f"{sd * 100:.0f} pt") == "60% ± 14 pt"
    assert mean_sd([2.0]) == "2.00" and mean_sd([]) == "n/a" and mean_sd([], empty="-") == "-"
    assert mean_sd([1.0, 3.0], lambda v: f"{v:.1f} cm", sep=" +- ") == "2.0 cm +- 1.4 cm"
    assert [significance(p) for p in (None, 0.01, 0.05)] == ["no test", "significant", "not significant"]


def test_the_markdown_table_writer() -> None:
    from spade.utils.markdown import markdown_table

    assert markdown_table(["a", "b"], [[1, "x"]]) == ["| a | b |", "|---|---|", "| 1 | x |"]
    assert markdown_table(["a", "b", "c"], [], "lr") == ["| a | b | c |", "|---|---:|---|"]
    assert markdown_table(["row", "n"], [["long row", "3"]], padded=True) == [
        "| row      | n |", "|----------|--:|", "| long row | 3 |"]


def test_every_page_is_registered_and_names_its_files() -> None:
    """spade.report's config checks learn a page's files from the registry, never from the page's module."""
    from spade.experiments.reporting.pages import PAGES, page, report_files

    assert set(PAGES) == {"closed_loop", "teacher", "oracle", "precision"}
    assert report_files("precision") == ["precision.md"]
    assert report_files("closed_loop") == ["closed_loop.md", "closed_loop.csv"]
    assert report_files("oracle") == ["oracle.md", "oracle_curve.png"]
    assert report_files("table2", chart=False) == ["table2.md", "table2.csv", "table2_comparisons.csv"]
    assert report_files("2") == report_files("table2") and "table1.png" in report_files("all")
    assert page("teacher").offline == ("teacher.records_dir", "teacher.committed")
    with pytest.raises(ValueError, match="unknown table 'nope'"):
        page("nope")
    source = (KERNEL.parents[2] / "config" / "report_checks.py").read_text()
    assert "spade.experiments" not in "".join(line for line in source.splitlines()
                                              if line.lstrip().startswith(("import", "from")))
