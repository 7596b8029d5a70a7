"""The oracle page from run records alone, and the bootstrap over scenarios it reads its intervals from."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from spade.experiments.reporting.intervals import paired_difference, scenario_interval


def test_a_scenario_interval_is_the_cluster_bootstrap_of_the_instance_mean() -> None:
    scenarios = ["a", "a", "b", "c", "c", "c"]
    values = [1.0, 3.0, 2.0, 4.0, 4.0, float("nan")]  # a NaN (failure) is left out, not averaged
    got = scenario_interval(scenarios, values, draws=4000)
    assert got.mean == pytest.approx(14 / 5) and got.scenarios == 3 and got.instances == 5
    # by hand: every resample of the three scenarios' (sum, count) pairs, each with probability 1/27
    pairs = {"a": (4.0, 2), "b": (2.0, 1), "c": (8.0, 2)}
    means = sorted(sum(pairs[k][0] for k in pick) / sum(pairs[k][1] for k in pick)
                   for pick in [(x, y, z) for x in pairs for y in pairs for z in pairs])
    assert means[0] <= got.low <= got.mean <= got.high <= means[-1]
    assert got.low == pytest.approx(np.percentile(means, 2.5), abs=0.35)
    assert got.high == pytest.approx(np.percentile(means, 97.5), abs=0.35)


def test_one_scenario_has_no_interval() -> None:
    got = scenario_interval(["a", "a"], [1.0, 2.0])
    assert got.mean == 1.5 and math.isnan(got.low)


def test_a_paired_difference_excludes_zero_only_when_one_side_is_consistently_lower() -> None:
    a = {f"s{i}": [1.0 + 0.01 * i] for i in range(30)}
    b = {f"s{i}": [2.0 + 0.01 * i] for i in range(30)}
    assert paired_difference(a, b).excludes_zero() and paired_difference(a, b).mean == pytest.approx(-1.0)
    noise = np.random.default_rng(0).normal(0, 1, 30)
    c = {f"s{i}": [1.0 + noise[i]] for i in range(30)}
    d = {f"s{i}": [1.0 - noise[i]] for i in range(30)}
    assert not paired_difference(c, {k: [1.0] for k in c}).excludes_zero() or abs(noise.mean()) > 0.3
    assert paired_difference(c, d).scenarios == 30


def _record(root: Path, row: str, seed: int, ape: float, rng: np.random.Generator) -> None:
    instances = [{"scenario": f"m/L{i // 3:03d}", "map": "m", "planner_ape_cm": float(ape + rng.normal(0, 0.3)),
                  "planner_plausibility_cm": 1.0, "planner_commit": 1.0, "planner_failed": 0.0} for i in range(90)]
    metrics = {"test/planner/ape_cm": float(np.mean([i["planner_ape_cm"] for i in instances])),
               "test/planner/over_20cm_rate": 0.0, "test/planner/plausibility_cm": 1.0,
               "test/planner/commit_rate": 0.9, "test/planner/ape_over_floor": ape / 2.0,
               "test/planner/failure_rate": 0.0, "test/floor_cm": 2.0, "test/ceiling/planner/ape_cm": 2.5,
               "test/ceiling/planner/ape_over_floor": 1.25, "test/ceiling/planner/over_20cm_rate": 0.0,
               "test/baseline/straight/planner/ape_cm": 24.0, "test/baseline/straight/planner/over_20cm_rate": 0.5,
               "test/baseline/shortest/planner/ape_cm": 19.0, "test/baseline/shortest/planner/over_20cm_rate": 0.4,
               "test/baseline/heading/planner/ape_cm": 13.0, "test/baseline/heading/planner/over_20cm_rate": 0.1}
    (root / f"{row}_s{seed}.json").write_text(json.dumps({
        "row": row, "seed": seed, "run_id": f"{row}{seed}", "start_time": 0, "end_time": 60_000,
        "metrics": metrics, "params": {}, "instances": instances}))


def test_the_page_regenerates_from_its_records_and_leads_with_its_verdict(tmp_path: Path) -> None:
    from spade.experiments.oracle_page import oracle_report

    records = tmp_path / "records"
    records.mkdir()
    rng = np.random.default_rng(0)
    for seed in (42, 1, 2):
        _record(records, "site_bc_L", seed, 4.0, rng)
        _record(records, "site_oracle_L", seed, 4.05, rng)  # not told apart
        _record(records, "site_oraclelabels_L", seed, 3.0, rng)  # clearly better
    settings = {"page": "oracle", "experiment": "oracle", "records_dir": str(records), "against": "site_bc_L",
                "rows": {"site_bc_L": "BC", "site_oracle_L": "oracle", "site_oraclelabels_L": "samples as labels"}}
    text, files = oracle_report(f"sqlite:///{tmp_path}/missing.db", tmp_path / "out", settings)
    assert text.index("## Verdict") < text.index("## Rows") < text.index("## Provenance")
    verdict = text.split("## Rows")[0]
    assert "**Better than BC**: samples as labels 2.9" in verdict or "**Better than BC**: samples as labels 3.0" in verdict
    assert re.search(r"\*\*Not told apart from BC\*\*: oracle 4\.\d\d cm", verdict) and "Holm" in verdict
    assert "the BC ceiling is 2.50 cm" in verdict
    assert "[" in text.split("## Rows")[1] and "Holm" in text  # intervals and the page's correction
    headline = text.split("## Rows")[1].split("## Tests")[0]
    assert all(line.count("|") <= 10 for line in headline.splitlines())  # at most 8 columns: fits the docs column
    tests = text.split("## Tests against BC")[1].split("??? note")[0]
    assert tests.index("samples as labels") < tests.index("| oracle |")  # the rows told apart first
    assert '??? note "Every figure of every row' in text
    assert "BC ceiling" in text and "straight line" in text
    assert files["markdown"].read_text().startswith("# Where a teacher teaches")
    assert not (tmp_path / "missing.db").exists()  # no store was created
    settings["rows"]["site_teacher_L"] = "never run"
    text, _ = oracle_report(f"sqlite:///{tmp_path}/missing.db", None, settings)
    assert "not run yet: never run (`+experiment=site_teacher_L`)" in text


def test_a_small_test_set_says_so_in_the_summary() -> None:
    from spade.tracking.summary import figure_lines

    small = "\n".join(figure_lines({"test/scenarios": 17.0, "test/floor_cm": 2.06,
                                    "test/ceiling/planner/ape_cm": 2.54, "test/ceiling/planner/ape_over_floor": 1.23,
                                    "test/ceiling/planner/plausibility_cm": 1.1,
                                    "test/ceiling/planner/commit_rate": 0.85,
                                    "test/demo_target/planner/ape_cm": 1.14}, []))
    assert "17 scenarios (a small test" in small and "data=site_L" in small
    assert "BC ceiling       : planner APE 2.54 cm, 1.23x the floor" in small and "commits 85%" in small
    assert "decoder floor    : planner APE 1.14 cm" in small
    large = "\n".join(figure_lines({"test/scenarios": 120.0}, []))
    assert "120 scenarios" in large and "small test" not in large


def test_the_data_size_curve_tests_each_size_against_bc_at_that_size_with_one_holm_family(tmp_path: Path) -> None:
    from spade.experiments.oracle_page import oracle_report

    records = tmp_path / "records"
    records.mkdir()
    rng = np.random.default_rng(1)
    for seed in (42, 1, 2):
        _record(records, "site_bc_250_L", seed, 6.0, rng)
        _record(records, "site_bcplaus_250_L", seed, 4.5, rng)  # clearly better at 250
        _record(records, "site_bc_L", seed, 4.0, rng)
        _record(records, "site_bcplaus_L", seed, 4.02, rng)  # the same at 500
    _record(records, "site_bc_2000_L", 42, 3.0, rng)  # one seed: never "told apart" over seeds
    settings = {"page": "oracle", "experiment": "oracle", "records_dir": str(records), "against": "site_bc_L",
                "rows": {"site_bc_L": "BC", "site_bcplaus_L": "BC plausible"},
                "curve": {"BC": {250: "site_bc_250_L", 500: "site_bc_L", 2000: "site_bc_2000_L"},
                          "BC plausible": {"250": "site_bcplaus_250_L", 500: "site_bcplaus_L"}}}
    text, files = oracle_report(f"sqlite:///{tmp_path}/missing.db", tmp_path / "out", settings)
    curve = text.split("## Data-size curve")[1].split("##")[0]
    assert "| series | 250 demonstrations | 500 demonstrations | 2,000 demonstrations |" in curve
    assert re.search(r"\| 2\.9\d \(1 seed\) \||\| 3\.0\d \(1 seed\) \|", curve) and "| floor | 2.00 | 2.00 | 2.00 |" in curve and "| BC ceiling | 2.50" in curve
    verdict = text.split("## Rows")[0]
    line = [x for x in verdict.splitlines() if x.startswith("- **Data-size curve**")][0]
    at_250, at_500 = line.split("at 500")
    assert re.search(r"at 250 demonstrations BC plans at (5\.9\d|6\.0\d) cm", at_250)
    assert re.search(r"BC plausible 4\.[45]\d cm \(-1\.\d\d, \d+ % of the gap; told apart\)", at_250)
    assert "not told apart" in at_500.split("at 2,000")[0]
    # the 500-demonstration comparison is one test, with one Holm-adjusted p, in the rows and in the curve
    row_500 = [x for x in text.split("## Tests against")[1].splitlines() if x.startswith("| BC plausible |")][0]
    holm_in_rows = float(row_500.split("|")[4])
    assert f"Holm p {holm_in_rows:.2g})" in curve
    assert files["curve"].is_file() and files["curve"].stat().st_size > 5_000
    assert "![planner APE against the number of demonstrations](oracle_curve.png)" in text
    # curve-only rows stay out of the rows table and its tests
    assert "site_bc_250_L" not in text.split("## Rows")[1].split("## Between")[0]


def test_a_malformed_curve_setting_names_the_fix() -> None:
    from spade.experiments.oracle_curve import curve_series

    with pytest.raises(ValueError, match="must map a number of demonstrations"):
        curve_series({"BC": ["site_bc_L"]})
    with pytest.raises(ValueError, match="not a whole number"):
        curve_series({"BC": {"many": "site_bc_L"}})


def test_a_row_that_loses_to_a_baseline_names_it() -> None:
    """A row whose seeds' mean planner APE and tail are worse than a classical baseline's is said to lose to it."""
    from spade.experiments.oracle_page import _losses
    from spade.experiments.run_records import RunRecord

    def run(seed: int, ape: float) -> RunRecord:
        metrics = {"test/planner/ape_cm": ape, "test/planner/over_20cm_rate": 0.4,
                   "test/baseline/heading/planner/ape_cm": 12.0, "test/baseline/heading/planner/over_20cm_rate": 0.1}
        return RunRecord(f"row_s{seed}", seed, f"run{seed}", None, None, metrics)

    assert _losses([run(1, 22.0), run(2, 25.0)]) == ["heading template"]
    assert _losses([run(1, 5.0), run(2, 6.0)]) == []


def test_the_precision_page_tells_a_moved_figure_from_noise(tmp_path: Path) -> None:
    """The bf16 science check: a bf16 row whose planner APE moved by 1 cm (5 sd) is told apart from its fp32 twin
    after Holm; one within the seeds' noise is not; a pair without two seeds on a side is said untested."""
    from spade.experiments.precision_page import precision_report

    records = tmp_path / "records"
    records.mkdir()
    rng = np.random.default_rng(1)
    for seed, jitter in zip((42, 1, 2, 3), (0.0, 0.2, -0.2, 0.1)):
        _record(records, "site_bc_L", seed, 4.0 + jitter, rng)
        _record(records, "site_bc_bf16_L", seed, 4.05 - jitter, rng)  # within noise
        _record(records, "site_teacher_L", seed, 4.0 + jitter / 4, rng)
        _record(records, "site_teacher_bf16_L", seed, 5.0 + jitter / 4, rng)  # moved by 1 cm
    _record(records, "site_x_bf16_L", 42, 4.0, rng)
    settings = {"records_dir": str(records), "labels": {"site_bc_bf16_L": "BC", "site_teacher_bf16_L": "teacher"},
                "pairs": {"site_bc_bf16_L": "site_bc_L", "site_teacher_bf16_L": "site_teacher_L",
                          "site_x_bf16_L": "site_x_L"}}
    text, files = precision_report(f"sqlite:///{tmp_path}/missing.db", tmp_path / "out", settings)
    verdict = text.split("## Figures")[0]
    assert "**bf16 changes the science**: told apart from fp32 on teacher: planner APE" in verdict
    assert "BC: planner APE" not in verdict and "Not yet tested" in verdict and "site_x_bf16_L" in verdict
    rows = {tuple(c.strip() for c in line.split("|")[1:3]): line for line in text.splitlines() if line.startswith("| ")}
    assert rows[("teacher", "planner APE")].rstrip(" |").endswith("told apart")
    assert rows[("BC", "planner APE")].rstrip(" |").endswith("not told apart")
    assert "(4) | 4." in rows[("BC", "planner APE")] and files["markdown"].read_text().startswith("# bf16")
    with pytest.raises(ValueError, match="precision.pairs is empty"):
        precision_report(f"sqlite:///{tmp_path}/missing.db", None, {"records_dir": str(records)})


def test_a_curve_point_counts_its_optimizer_steps_from_its_params() -> None:
    """max_steps when it stopped the run, else epochs times the batches (the last one partial) of the training set."""
    from spade.experiments.oracle_page import optimizer_steps
    from spade.experiments.run_records import RunRecord

    def record(**params: str) -> RunRecord:
        return RunRecord(row="r", seed=1, run_id="x", start_time=0, end_time=1, metrics={}, params={f"cfg/{k.replace('__', '/')}": v
                                                                       for k, v in params.items()})

    assert optimizer_steps(record(trainer__max_epochs="6", data__max_train_instances="500")) == 96  # 16 batches of 32
    assert optimizer_steps(record(trainer__max_epochs="12", data__max_train_instances="250")) == 96
    assert optimizer_steps(record(trainer__max_epochs="-1", trainer__max_steps="96",
                                  data__max_train_instances="2000")) == 96
    assert optimizer_steps(record(trainer__max_epochs="2", data__max_train_instances="100", data__batch_size="16")) == 14
    assert optimizer_steps(record(trainer__max_epochs="6")) is None


def test_a_row_with_a_twin_is_tested_against_it_and_the_twin_is_a_reference(tmp_path: Path) -> None:
    """against_rows: the small student's label route against the small BC, not the medium one; the small BC itself
    is a reference (not tested against the medium BC)."""
    from spade.experiments.oracle_page import oracle_report

    records = tmp_path / "records"
    records.mkdir()
    rng = np.random.default_rng(2)
    for seed in (42, 1, 2):
        _record(records, "site_bc_L", seed, 4.0, rng)
        _record(records, "site_bc_small_L", seed, 6.0, rng)
        _record(records, "site_bcplaus_small_L", seed, 5.0, rng)  # better than the small BC, worse than the medium
    settings = {"page": "oracle", "records_dir": str(records), "against": "site_bc_L",
                "rows": {"site_bc_L": "BC", "site_bc_small_L": "BC small", "site_bcplaus_small_L": "plaus small"},
                "against_rows": {"site_bcplaus_small_L": "site_bc_small_L"}}
    text, _ = oracle_report(f"sqlite:///{tmp_path}/missing.db", None, settings)
    verdict = text.split("## Rows")[0]
    assert re.search(r"\*\*Better than BC\*\*: plaus small \d\.\d\d cm \(-\d\.\d\d against BC small", verdict)
    assert "BC small 6." not in verdict  # the reference is not tested
    headline = next(line for line in text.splitlines() if line.startswith("| plaus small |"))
    assert "better (against BC small)" in headline
    assert next(line for line in text.splitlines() if line.startswith("| BC small |")).rstrip(" |").endswith("—")
