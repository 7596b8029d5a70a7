"""The teacher page (spade.report table=teacher) from hand-made MLflow runs: experts as planners beside their
students, the targets against the student of the same markers, and guided students against their BC twins."""

from __future__ import annotations

from pathlib import Path

import pytest


def _run(client, experiment: str, name: str, seed: int, encoding: str, metrics: dict[str, float]) -> None:  # noqa: ANN001
    run = client.create_run(experiment, run_name=name, tags={"scale": "quickstart"})
    rid = run.info.run_id
    client.log_param(rid, "cfg/seed", seed)
    client.log_param(rid, "cfg/data/encoding", encoding)
    for key, value in metrics.items():
        client.log_metric(rid, key, value)
    client.set_terminated(rid, "FINISHED")


def test_the_teacher_page_checks_each_expert_against_its_student_and_guidance_against_bc(tmp_path: Path) -> None:
    from mlflow import MlflowClient

    from spade.experiments.teacher_table import teacher_report

    uri = f"sqlite:///{tmp_path}/mlflow.db"
    client = MlflowClient(tracking_uri=uri)
    teacher, encoding = client.create_experiment("teacher"), client.create_experiment("encoding")
    # a good teacher on Gaussian markers: plausible, 0.5x its student's APE, but narrower than the generator
    _run(client, teacher, "good", 42, "gaussian", {
        "test/planner/ape_cm": 2.0, "test/planner/plausibility_cm": 0.8, "test/planner/spread_ratio": 0.5,
        "test/generator_spread_cm": 4.0, "test/seconds_per_sample": 0.01, "test/mean_map/planner/ape_cm": 1.9,
        "test/planner/over_20cm_rate": 0.0, "model/params": 741769.0})
    # a binary expert no better than its student
    _run(client, teacher, "old", 42, "binary", {"test/planner/ape_cm": 4.3, "test/planner/plausibility_cm": 2.2,
                                                "test/planner/spread_ratio": 0.67, "test/generator_spread_cm": 4.1})
    for seed, (gauss, binary) in enumerate([(3.9, 4.2), (4.0, 4.3), (4.1, 4.4)]):
        _run(client, encoding, "bc_gauss", seed, "gaussian", {
            "test/planner/ape_cm": gauss, "test/planner/plausibility_cm": 2.0 + seed / 10,
            "test/baseline/shortest/planner/ape_cm": 40.0, "test/planner/commit_rate": 0.1,
            "test/planner/over_20cm_rate": 0.01})
        _run(client, encoding, "bc_binary", seed, "binary", {"test/planner/ape_cm": binary,
                                                             "test/planner/plausibility_cm": 2.1})
        _run(client, teacher, "guided", seed, "gaussian", {
            "test/planner/ape_cm": gauss - 0.05, "test/planner/plausibility_cm": 1.9, "margin/active": 0.3,
            "test/planner/commit_rate": 0.2, "test/planner/over_20cm_rate": 0.01})
    # the closed loop: the guided row and its twin driven on the held-out map, clean (spade.closed_loop's runs)
    loop = client.create_experiment("closed_loop")
    for seed in range(3):
        for source, ape in (("guided", 12.0 + seed), ("bc_gauss", 14.0 + seed)):
            drive = client.create_run(loop, run_name=f"{source}__heldout__clean", tags={
                "scale": "quickstart", "source_row": source, "dataset": "heldout", "condition": "clean"}).info.run_id
            client.log_param(drive, "cfg/seed", seed)
            client.log_metric(drive, "closed_loop/success_rate", 1.0)
            client.log_metric(drive, "closed_loop/ape_cm", ape)
            client.set_terminated(drive, "FINISHED")
    trained = client.create_run(teacher, run_name="good_training").info.run_id
    client.log_param(trained, "cfg/trainer/max_epochs", 48)
    client.set_terminated(trained, "FAILED")
    settings = {
        "experts": [{"table": "teacher", "row": "good", "label": "good teacher",
                     "trained_by": {"table": "teacher", "row": "good_training", "note": "after its test"}},
                    {"table": "teacher", "row": "old", "label": "old expert"},
                    {"table": "teacher", "row": "never_ran", "label": "unrun"}],
        "students": [{"table": "encoding", "row": "bc_binary", "label": "BC binary"},
                     {"table": "encoding", "row": "bc_gauss", "label": "BC gaussian"}],
        "guided": [{"table": "teacher", "row": "guided", "label": "Cond-DBC",
                    "against": {"table": "encoding", "row": "bc_gauss"}}],
    }
    text, files = teacher_report(uri, tmp_path / "out", settings, "quickstart")
    assert files["markdown"].read_text() == text and files["csv"].is_file()
    assert "| good teacher, one sample | gaussian | 1 | 2.00 |" in text
    good_row = next(line for line in text.splitlines() if line.startswith("| good teacher, one sample |"))
    assert good_row.endswith("| 0.50 | 10 | 0.74 M |")  # spread ratio, ms per sample, network size
    assert text.startswith("# The teacher: each expert as a planner beside its student\n")
    assert "| BC gaussian | gaussian | 3 | 4.00 ± 0.10 |" in text
    assert "| unrun | ? | 0 | missing" in text
    # the baselines (which read no marker) once, from the first student row that has them (bc_gauss)
    assert sum(line.startswith("| shortest path (Nav2-like) | - | - | 40.00 |") for line in text.splitlines()) == 1
    good = next(line for line in text.splitlines() if line.startswith("- good teacher against BC gaussian"))
    assert "plausibility 0.80 cm (target ≤ 1.0: met)" in good
    assert "planner APE 2.00 cm = 0.50x the student's 4.00 (target ≤ 0.8x = 3.20 cm: met)" in good
    assert "spread 0.50x the generator's (target within ±20%: not met)" in good
    assert "4.00 cm, above the APE target" in good  # a calibrated single sample cannot be at 0.8x here
    old = next(line for line in text.splitlines() if line.startswith("- old expert against BC binary"))
    assert "plausibility 2.20 cm (target ≤ 1.0: not met)" in old and "(target ≤ 0.8x = 3.44 cm: not met)" in old
    # one-sample tests with Holm, and the verdict in words
    assert "the expert plans better than its student by planner APE (2.00 vs 4.00 cm), significant" in text
    assert "| old expert vs BC binary | planner/ape_cm | 4.30 | 4.30 |" in text
    # guidance against the BC twin: Welch, the margin's activity; the real-map rows are missing and untested
    assert "| Cond-DBC | held-out map | 3 | 3.95 ± 0.10 |" in text and "| 30% |" in text  # constant: no sd
    assert "| Cond-DBC | unseen real maps | 0 | missing |" in text
    # the closed loop beside them where the rows were driven, tested like the rest; "not driven" elsewhere
    held = next(line for line in text.splitlines() if line.startswith("| Cond-DBC | held-out map |"))
    assert "| 100% | 13.00 ± 1.00 | 30% |" in held
    assert "| not driven | not driven | missing |" in text
    assert "| Cond-DBC vs BC twin (bc_gauss), held-out map | closed_loop/ape_cm | 13.00 | 15.00 |" in text
    assert "| Cond-DBC vs BC twin (bc_gauss), held-out map | planner/ape_cm | 3.95 | 4.00 |" in text
    assert "the first plans better by planner APE (3.95 vs 4.00 cm), not significant" in text
    assert "- commit: " in text and "- machine: " in text
    assert "- wall time of the guided rows, their BC twins and their drives counted: " in text
    assert "- good teacher: run `teacher/good_training`" in text and "status FAILED (after its test)" in text
    assert "trainer/max_epochs=48" in text
    assert "Test set (MLflow dataset input, name and digest): not recorded, scale quickstart." in text
    # a lever page of experts alone (conf/teacher/width.yaml): its own title and files, no guidance section
    lever = {"page": "teacher_lever", "title": "A lever", "experts": settings["experts"][:1],
             "students": settings["students"], "guided": []}
    text, files = teacher_report(uri, tmp_path / "out", lever, "quickstart")
    assert text.startswith("# A lever\n") and files["markdown"].name == "teacher_lever.md"
    assert "Guidance from the teacher" not in text and "guided rows" not in text
    assert "the expert plans better than its student by planner APE (2.00 vs 4.00 cm)" in text


def test_the_teacher_page_is_a_report_table(tmp_path: Path) -> None:
    """spade.report table=teacher composes, checks its output files and names them."""
    from spade.experiments.reporting.pages import page, report_files
    from spade.utils.config import compose_config

    assert report_files("teacher") == ["teacher.md", "teacher.csv"]
    cfg = compose_config("report", ["table=teacher", f"paths.root_dir={tmp_path}"])
    assert [e["row"] for e in cfg.teacher.experts][0] == "teacher_shipped_binary"
    assert cfg.teacher.guided[0].against.row == "enc_gaussian_L"
    # another page of the group: its own rows and files, so it never replaces the main page
    width = compose_config("report", ["table=teacher", "teacher=width", f"paths.root_dir={tmp_path}"])
    assert [e["row"] for e in width.teacher.experts] == ["teacher_L", "teacher_wide_L"]
    assert report_files("teacher", teacher_page=width.teacher.page) == ["teacher_width.md", "teacher_width.csv"]
    from spade.config.report_checks import validate_report_config
    from spade.utils.errors import ConfigError

    bad = compose_config("report", ["table=teacher", "teacher.page=../teacher", f"paths.root_dir={tmp_path}"])
    with pytest.raises(ConfigError, match=r"teacher.page='../teacher' is not a file name; set teacher.page=NAME"):
        validate_report_config(bad, page)
    pytest.importorskip("scipy")


def test_early_stopping_is_offered_as_a_callback(tmp_path: Path) -> None:
    """+callbacks/extra@callbacks.early_stopping=early_stopping adds Lightning's EarlyStopping on the optimized metric."""
    from lightning.pytorch.callbacks import EarlyStopping

    from spade.config.preflight import validate_train_config
    from spade.training.instantiate import instantiate_callbacks
    from spade.utils.config import compose_config

    cfg = compose_config("train", ["+experiment=quickstart", f"paths.root_dir={tmp_path}",
                                   "+callbacks/extra@callbacks.early_stopping=early_stopping",
                                   "callbacks.early_stopping.patience=3", f"paths.output_dir={tmp_path}/out"])
    validate_train_config(cfg)
    stops = [cb for cb in instantiate_callbacks(cfg.callbacks) if isinstance(cb, EarlyStopping)]
    assert len(stops) == 1 and stops[0].monitor == "val/score_cm" and stops[0].patience == 3
