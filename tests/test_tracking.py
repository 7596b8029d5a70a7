"""What a run records in MLflow for a person reading it: the method's parameters without bookkeeping, the
baselines and the untrained model as child runs under the model's metric names (never counted as seeds of a row),
the run's report and training-progress picture, process tags only while a run runs. The references are only child
runs, every test figure sits at one step, the margin shares the validation's x axis, each predictor kind has its
colour (one palette for previews, plan pictures and prediction pictures), the description opens with the figures'
table (units, rounded) and states the test set's composition and the measured wall time; readers fold the child
runs back in.

The pieces are tested on a SQLite store without training (seconds); one tiny quickstart run, in-process, checks
that ``spade.train`` puts them all together.
"""

from __future__ import annotations

import csv
import json
import os
from pathlib import Path
from types import SimpleNamespace

import pytest

# A tested student's metrics as the test step logs them: its own, the classical baselines', the untrained model's.
METRICS = {
    "test/ape_cm": 4.5, "test/hd19": 3.0, "test/failure_rate": 0.02, "test/planner/ape_cm": 5.5,
    "model/params": 118165.0,
    "test/baseline/straight/ape_cm": 30.25, "test/baseline/straight/failure_rate": 0.0,
    "test/baseline/straight/planner/ape_cm": 30.5,
    "test/baseline/heading/ape_cm": 12.0, "test/baseline/heading/hd19": 1.0,
    "untrained/ape_cm": 190.0, "untrained/failure_rate": float("nan"), "untrained/planner/ape_cm": 80.0,
    "untrained/baseline/straight/ape_cm": 30.25,  # the baselines next to the untrained test: the same figures again
}


def _client(tmp_path: Path):
    from mlflow import MlflowClient

    return MlflowClient(tracking_uri=f"sqlite:///{tmp_path}/mlflow.db")


def _row_run(client, experiment_id: str, name: str, metrics: dict[str, float], seed: int = 7,
             status: str = "FINISHED") -> str:
    run = client.create_run(experiment_id, run_name=name, tags={"table": "table3", "row": name, "scale": "tiny",
                                                                 "shape": "U", "role": "student",
                                                                 "approach": "BC", "size": "small"})
    client.log_param(run.info.run_id, "cfg/seed", seed)
    for key, value in metrics.items():
        client.log_metric(run.info.run_id, key, value)
    if status != "RUNNING":
        client.set_terminated(run.info.run_id, status)
    return run.info.run_id


# -- parameters ---------------------------------------------------------------------------------------------------
def test_params_describe_the_method_without_bookkeeping_or_copies(tmp_path: Path) -> None:
    """About 180 params started with ``cfg/task_name`` and ``cfg/seeds None`` and held every setting twice
    (``cfg/model/margin/lambda_dm`` beside Lightning's ``margin/lambda_dm``, the recipe's and the scale's copies)."""
    from omegaconf import OmegaConf

    from spade.tracking.params import run_params
    from training_helpers import compose_row

    cfg = compose_row("quickstart", tmp_path)
    params = run_params(OmegaConf.to_container(cfg, resolve=True))
    keys = set(params)
    for wanted in ("cfg/model/optimizer/lr", "cfg/model/margin/lambda_dm", "cfg/model/size", "cfg/model/margin/score",
                   "cfg/model/margin/clip", "cfg/model/margin/agent_input", "cfg/model/bc_pos_weight",
                   "cfg/recipe/name", "cfg/scale/name", "cfg/scale/train_instances", "cfg/scale/test_instances",
                   "cfg/scale/image_size", "cfg/data/batch_size", "cfg/trainer/max_epochs", "cfg/seed",
                   "cfg/run_name", "cfg/metrics/hd_threshold_m"):
        assert wanted in keys, wanted
    # the resume check reads these (spade.config.preflight.RESUME_KEYS); spade.report reads cfg/seed
    assert {"cfg/run_name", "cfg/seed", "cfg/model/size", "cfg/scale/name"} <= keys
    assert params["cfg/model/optimizer"] == "AdamW" and params["cfg/model/lr_scheduler"] == "warmup_cosine"
    assert params["cfg/model/margin/lambda_dm"] == cfg.model.margin.lambda_dm
    for dropped in ("cfg/task_name", "cfg/seeds", "cfg/rows", "cfg/threads", "cfg/ckpt_path", "cfg/test_untrained",
                    "cfg/recipe/lambda_dm", "cfg/scale/batch_size", "cfg/model/metrics/pred_threshold",
                    "cfg/trainer/max_steps", "cfg/trainer/enable_progress_bar", "cfg/model/grid_size"):
        assert dropped not in keys, dropped
    forbidden = ("cfg/hydra", "cfg/paths/", "cfg/logger/", "cfg/callbacks/", "cfg/tags/", "cfg/requires/",
                 "cfg/registry/", "cfg/data/train_generate/", "cfg/data/test_generate/")
    assert not [k for k in keys if k.startswith(forbidden)]
    assert not [k for k in keys if k.endswith(("_target_", "_partial_", "_convert_", "_dir", "_ckpt"))]
    assert all(v is not None for v in params.values())
    assert not [v for v in params.values() if str(v).startswith(str(tmp_path))]  # no path of this machine
    assert 20 <= len(params) <= 60, sorted(params)


# -- predictors as child runs ------------------------------------------------------------------------------------
def test_baselines_and_the_untrained_model_are_child_runs_with_the_model_metric_names(tmp_path: Path) -> None:
    from spade.tracking.experiment_tags import VIEW_TAG, ensure_experiment_tags
    from spade.tracking.predictors import (PARENT_TAG, PREDICTOR_TAG, TOP_LEVEL_FILTER, is_predictor_run,
                                           log_predictor_runs)

    client = _client(tmp_path)
    experiment_id = client.create_experiment("table3", artifact_location=str(tmp_path / "artifacts"))
    ensure_experiment_tags(client, client.get_experiment(experiment_id))  # as spade.train tags it
    parent = _row_run(client, experiment_id, "t3_bc_scratch_U", METRICS)
    children = log_predictor_runs(client, parent, "student", "BC student")
    assert sorted(children) == ["baseline-heading", "baseline-straight", "untrained"]
    runs = {r.info.run_name: r for r in client.search_runs([experiment_id])}
    assert sorted(runs) == ["t3_bc_scratch_U", "t3_bc_scratch_U/baseline-heading", "t3_bc_scratch_U/baseline-straight",
                            "t3_bc_scratch_U/untrained"]
    assert runs["t3_bc_scratch_U"].data.tags[PREDICTOR_TAG] == "student"
    straight = runs["t3_bc_scratch_U/baseline-straight"]
    assert straight.data.metrics == {"test/ape_cm": 30.25, "test/failure_rate": 0.0, "test/planner/ape_cm": 30.5}
    assert straight.info.status == "FINISHED" and straight.data.tags[PARENT_TAG] == parent
    assert {k: straight.data.tags[k] for k in ("table", "row", "scale", "shape", PREDICTOR_TAG)} == {
        "table": "table3", "row": "t3_bc_scratch_U", "scale": "tiny", "shape": "U", PREDICTOR_TAG: "baseline-straight"}
    assert "straight line" in straight.data.tags["mlflow.note.content"]
    untrained = runs["t3_bc_scratch_U/untrained"]
    assert untrained.data.metrics["test/ape_cm"] == 190.0 and untrained.data.metrics["model/params"] == 118165.0
    assert not [k for k in untrained.data.metrics if "baseline" in k or k.startswith("untrained/")]
    assert untrained.data.tags["approach"] == "BC" and "BC student" in untrained.data.tags["mlflow.note.content"]
    # no metric name is prefixed by another predictor's name
    assert all(k.startswith(("test/", "model/")) and "/baseline/" not in k
               for r in runs.values() if r.info.run_name != "t3_bc_scratch_U" for k in r.data.metrics)
    assert [is_predictor_run(r) for r in runs.values()].count(True) == 3
    top = client.search_runs([experiment_id], filter_string=TOP_LEVEL_FILTER)
    assert [r.info.run_id for r in top] == [parent]
    # SPADE's runs view sorts by name: the run, then its predictors, one line each, the same columns
    view = json.loads(client.get_experiment(experiment_id).tags[VIEW_TAG])
    assert (view["orderByKey"], view["orderByAsc"]) == ("tags.`mlflow.runName`", True)
    # ... its first columns the rounded figures, the deciding one first, which every predictor's run carries
    assert view["selectedColumns"][:2] == ["tags.`planner APE`", "tags.`planner over 20 cm`"]
    assert view["columnOrder"] == view["selectedColumns"] and view["selectedColumns"][-1] == "attributes.`Dataset`"
    assert straight.data.tags["planner APE"] == "30.50 cm" and straight.data.tags["APE"] == "30.25 cm"
    assert untrained.data.tags["params"] == "118k"
    assert sorted(runs) == [r.info.run_name for r in client.search_runs(
        [experiment_id], order_by=["tags.`mlflow.runName` ASC"])]
    # logged again (a run tested again): updated, not doubled
    client.log_metric(parent, "test/baseline/straight/ape_cm", 31.0)
    assert log_predictor_runs(client, parent, "student") == children
    assert len(client.search_runs([experiment_id])) == 4
    assert client.get_run(children["baseline-straight"]).data.metrics["test/ape_cm"] == 31.0
    # a run without baselines or untrained figures has no children
    lone = _row_run(client, experiment_id, "t3_augbc_pretrained_expert_U", {"test/ape_cm": 2.0})
    assert log_predictor_runs(client, lone, "expert") == {} and len(client.search_runs([experiment_id])) == 5


def test_report_and_run_summary_do_not_take_child_runs_for_seeds_of_a_row(tmp_path: Path) -> None:
    from omegaconf import OmegaConf

    from spade.experiments.reporting import fetch_results
    from spade.tracking.tables import TABLES
    from spade.tracking.predictors import log_predictor_runs
    from spade.tracking.summary import find_run

    client = _client(tmp_path)
    experiment_id = client.create_experiment("table3", artifact_location=str(tmp_path / "artifacts"))
    first = _row_run(client, experiment_id, "t3_bc_scratch_U", METRICS, seed=1)
    second = _row_run(client, experiment_id, "t3_bc_scratch_U", {**METRICS, "test/ape_cm": 5.5}, seed=2)
    for run_id in (first, second):
        log_predictor_runs(client, run_id, "student")
    # a predictor's run renamed as its row (a person editing names in the UI): still never a seed of the row
    stray = log_predictor_runs(client, second, "student")["untrained"]
    client.set_tag(stray, "mlflow.runName", "t3_bc_scratch_U")
    row = fetch_results(TABLES["table3"], f"sqlite:///{tmp_path}/mlflow.db", "tiny")["t3_bc_scratch_U"]
    assert row.n == 2 and sorted(row.run_ids) == sorted([first, second]) and row.n_runs == 2
    assert row.value("ape_cm") == pytest.approx(5.0) and row.value("straight/ape_cm") == pytest.approx(30.25)
    cfg = OmegaConf.create({"run_name": "t3_bc_scratch_U", "paths": {"mlflow_tracking_uri":
                                                                   f"sqlite:///{tmp_path}/mlflow.db"},
                            "logger": {"mlflow": {"experiment_name": "table3"}}})
    assert find_run(cfg).run_id == second  # the row's latest own run, not its child renamed after it


def test_stale_running_runs_are_closed_but_a_childs_name_is_no_row(tmp_path: Path) -> None:
    import socket
    import subprocess

    from omegaconf import OmegaConf

    from spade.tracking.runs import mark_stale_runs

    client = _client(tmp_path)
    experiment_id = client.create_experiment("table3")
    gone = subprocess.Popen(["true"])
    gone.wait()  # a pid that is no longer running
    stale = _row_run(client, experiment_id, "t3_bc_scratch_U", {}, status="RUNNING")
    child = _row_run(client, experiment_id, "t3_bc_scratch_U", {}, status="RUNNING")
    for run_id in (stale, child):
        for key, value in (("spade.host", socket.gethostname()), ("spade.pid", str(gone.pid))):
            client.set_tag(run_id, key, value)
    client.set_tag(child, "mlflow.parentRunId", stale)
    cfg = OmegaConf.create({"logger": {"mlflow": {"_target_": "lightning.pytorch.loggers.MLFlowLogger",
                                                  "tracking_uri": f"sqlite:///{tmp_path}/mlflow.db",
                                                  "experiment_name": "table3", "run_name": "t3_bc_scratch_U"}}})
    messages = mark_stale_runs(cfg)
    assert len(messages) == 1 and stale in messages[0]
    assert client.get_run(stale).info.status == "KILLED" and client.get_run(child).info.status == "RUNNING"


def test_process_tags_are_kept_while_a_run_runs_or_after_it_failed_and_dropped_when_it_finished(
        tmp_path: Path) -> None:
    """``spade.pid`` / ``spade.host`` / ``spade.proc_start`` are process noise on a finished run; they
    identify a RUNNING run's process (mark_stale_runs) and a failed run's (diagnosis), so only those keep them."""
    from lightning.pytorch.loggers import MLFlowLogger

    from spade.tracking.runs import (
        PROCESS_TAGS, bind_experiment, drop_process_tags, mark_run_ended, record_process,
    )

    def run(name: str):
        ml = MLFlowLogger(experiment_name="status", tracking_uri=f"sqlite:///{tmp_path}/mlflow.db", run_name=name)
        bind_experiment(ml)
        record_process([ml], resumed=False)
        return ml

    running, finished, failed = run("running"), run("finished"), run("failed")
    finished.experiment.set_terminated(finished.run_id, "FINISHED")
    mark_run_ended([failed], RuntimeError("boom"))
    for ml in (running, finished, failed):
        drop_process_tags(ml.experiment, ml.run_id)
    tags = {ml: ml.experiment.get_run(ml.run_id).data.tags for ml in (running, finished, failed)}
    assert tags[running]["spade.pid"] == str(os.getpid()) and set(PROCESS_TAGS) & set(tags[running])
    assert not set(PROCESS_TAGS) & set(tags[finished])
    assert tags[failed]["spade.pid"] == str(os.getpid()) and tags[failed]["spade.end_reason"] == "RuntimeError: boom"


# -- the run's report and its training-progress picture ----------------------------------------------------------
def test_the_run_report_holds_the_description_and_every_predictors_figures(tmp_path: Path) -> None:
    from spade.tracking.run_report import CSV_KEYS, write_run_report

    files = write_run_report(tmp_path, "t3_bc_scratch_U", "**t3_bc_scratch_U**: BC student.\n\n| table |", METRICS,
                             "student")
    text = files["markdown"].read_text()
    assert text.startswith("# Run `t3_bc_scratch_U`") and "BC student" in text and "test_figures.csv" in text
    with open(files["csv"]) as fh:
        rows = {r["predictor"]: r for r in csv.DictReader(fh)}
    assert list(rows) == ["student", "baseline-heading", "baseline-straight", "untrained"]
    assert float(rows["student"]["test/ape_cm"]) == 4.5 and float(rows["baseline-straight"]["test/ape_cm"]) == 30.25
    assert rows["untrained"]["test/failure_rate"] == "nan" and rows["baseline-heading"]["test/fid"] == ""
    assert rows["baseline-straight"]["label"] == "baseline: straight line"
    assert set(CSV_KEYS) <= set(rows["student"])
    assert "csv" not in write_run_report(tmp_path / "untested", "x", "No test figures.", {"val/ape_cm": 1.0})


class _History:
    """A stand-in for MlflowClient's metric reads: ``{key: [(step, timestamp, value), ...]}``."""

    def __init__(self, history: dict[str, list[tuple[int, int, float]]]) -> None:
        self.history = history

    def get_run(self, run_id: str):
        return SimpleNamespace(data=SimpleNamespace(metrics={k: v[-1][2] for k, v in self.history.items()}, tags={}))

    def get_metric_history(self, run_id: str, key: str):
        return [SimpleNamespace(step=s, timestamp=t, value=v) for s, t, v in self.history.get(key, [])]


def test_training_progress_is_read_by_epoch_and_drawn() -> None:
    from spade.tracking.progress_picture import epoch_series, progress_picture

    history = _History({
        # Lightning: "epoch" beside every logged step; step 4 is both epoch 0's validation and epoch 1's first log
        "epoch": [(1, 10, 0.0), (3, 20, 0.0), (4, 30, 0.0), (4, 40, 1.0), (6, 50, 1.0), (8, 60, 1.0)],
        "train/loss": [(1, 10, 2.0), (3, 20, 1.0), (4, 40, 0.9), (6, 50, 0.7)],
        "val/loss_bc": [(4, 30, 0.8), (8, 60, 0.6)],
        "val/ape_cm": [(4, 30, float("nan")), (8, 60, 40.0)],
        "margin/active": [(0, 25, 1.0), (1, 55, 0.25)],  # step = epoch
        "margin/value": [(0, 25, 0.5), (1, 55, 0.1)],
        "test/ape_cm": [(9, 70, 30.0)],  # not a training curve
    })
    series = epoch_series(history, "run")
    assert series["train/loss"] == [(0, 1.5), (1, 0.8)]
    assert series["val/loss_bc"] == [(0, 0.8), (1, 0.6)] and series["val/ape_cm"] == [(1, 40.0)]
    assert series["margin/active"] == [(0, 1.0), (1, 0.25)] and "test/ape_cm" not in series
    picture = progress_picture(series, "row: training by epoch")
    assert picture.dtype.name == "uint8" and picture.shape[2] == 3 and picture.shape[1] >= 3 * picture.shape[0]
    unguided = progress_picture({k: v for k, v in series.items() if not k.startswith("margin/")})
    assert unguided.shape[1] < picture.shape[1]  # two panels: no guidance to show
    assert progress_picture({}) is None


# -- one tiny run, in-process -----------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def tracked_run(spade_home: Path):
    """One tiny quickstart student run (trained, tested, logged to MLflow): (config, train()'s objects)."""
    from spade.experiments.run import train
    from training_helpers import compose_row

    cfg = compose_row("quickstart", spade_home, "trainer.max_epochs=2", "+trainer.limit_train_batches=2",
                      "+trainer.limit_val_batches=1", "+trainer.limit_test_batches=1", "trainer.log_every_n_steps=1",
                      "trainer.enable_progress_bar=false", "model.grid_size=0", "callbacks.model_info.latency_runs=0",
                      "data.batch_size=4", "data.eval_batch_size=8", "+trainer.num_sanity_val_steps=0",
                      "metrics.fid_extractor=randconv", "tags.table=tracking_check", "run_name=tracked")
    _, objects = train(cfg)
    return cfg, objects


def test_a_tested_run_has_its_predictors_report_picture_and_lean_params(tracked_run) -> None:
    from mlflow import MlflowClient

    from spade.tracking.predictors import PREDICTOR_TAG

    cfg, _ = tracked_run
    client = MlflowClient(tracking_uri=str(cfg.paths.mlflow_tracking_uri))
    experiment = client.get_experiment_by_name("tracking_check")
    runs = {r.info.run_name: r for r in client.search_runs([experiment.experiment_id])}
    assert sorted(runs) == ["tracked", "tracked/baseline-heading", "tracked/baseline-shortest",
                            "tracked/baseline-straight", "tracked/untrained"]
    run = runs["tracked"]
    assert run.info.status == "FINISHED" and run.data.tags[PREDICTOR_TAG] == "student"
    for name, child in runs.items():
        if name != "tracked":
            assert {"test/ape_cm", "test/planner/ape_cm", "test/failure_rate", "test/over_20cm_rate"} <= set(
                child.data.metrics), name
            # the test set carries alternative demonstrations, so every predictor has the figures that
            # see a preference, beside the floor
            assert {"test/floor_cm", "test/planner/ape_over_floor", "test/planner/plausibility_cm",
                    "test/planner/commit_rate"} <= set(child.data.metrics), name
            assert child.data.tags["mlflow.parentRunId"] == run.info.run_id
            assert [d.dataset.name for d in child.inputs.dataset_inputs] == ["tiny/test"]
    params = run.data.params
    assert len(params) <= 60 and "cfg/task_name" not in params and "margin/lambda_dm" not in params
    assert params["cfg/model/margin/lambda_dm"] == str(cfg.model.margin.lambda_dm)
    assert not {"spade.pid", "spade.host", "spade.proc_start"} & set(run.data.tags)
    artifacts = {a.path for a in client.list_artifacts(run.info.run_id)}
    assert {"training_progress.png", "report", "config", "checkpoints"} <= artifacts
    assert {a.path for a in client.list_artifacts(run.info.run_id, "report")} == {"report/run_report.md",
                                                                                 "report/test_figures.csv"}
    note = run.data.tags["mlflow.note.content"]
    assert "child runs of this run" in note and "report/run_report.md" in note and "training_progress.png" in note
    assert "APE cm: mean distance between" in note
    assert "test/floor_cm" in run.data.metrics and "**Verdict.** Deciding figure" in note
    history = client.get_metric_history(run.info.run_id, "margin/active")
    # the margin at the global step of its epoch's validation, so that the UI's charts line them up
    val_steps = {m.step for m in client.get_metric_history(run.info.run_id, "val/ape_cm")}
    assert len(history) == 2 and {m.step for m in history} <= val_steps, (history, val_steps)
    assert run.data.tags["spade.margin_step"] == "global"


# -- the student as an MLflow Model on its own run -----------------------------------------------------------------
def test_a_student_run_logs_its_best_checkpoint_as_an_mlflow_model_on_its_run(tracked_run) -> None:
    """The run's deliverable is in its Models column: ``runs:/RUN_ID/model`` (ONNX, not registered)
    reproduces the best checkpoint's logits; the description and the closing lines name the URI for spade.plan."""
    import mlflow
    import numpy as np
    import torch
    from mlflow import MlflowClient
    from mlflow.entities import LoggedModelStatus

    from spade.deploy.export import example_states
    from spade.deploy.mlflow_models import resolve_model, using_tracking_uri
    from spade.training.checkpoint_paths import best_checkpoint_path
    from spade.tracking.summary import run_summary
    from spade.models.modelfile import load_network
    from factories import PARITY_BOUND

    cfg, objects = tracked_run
    uri = str(cfg.paths.mlflow_tracking_uri)
    client = MlflowClient(tracking_uri=uri)
    experiment = client.get_experiment_by_name("tracking_check")
    run = [r for r in client.search_runs([experiment.experiment_id]) if r.info.run_name == "tracked"][0]
    run_id = run.info.run_id
    outputs = run.outputs.model_outputs
    assert len(outputs) == 1
    model = client.get_logged_model(outputs[0].model_id)
    assert model.name == "model" and model.source_run_id == run_id and model.status == LoggedModelStatus.READY
    assert model.experiment_id == experiment.experiment_id
    assert not client.search_model_versions(f"run_id = '{run_id}'")  # logged, not registered
    assert run.info.status == "FINISHED"

    state = example_states(3, (64, 64), seed=4)
    net, _ = load_network(best_checkpoint_path(objects["trainer"]), role="student")
    with torch.inference_mode():
        expected = net.eval()(state).numpy()
    with using_tracking_uri(uri):
        info = mlflow.models.get_model_info(f"runs:/{run_id}/model")
        loaded = mlflow.pyfunc.load_model(f"runs:/{run_id}/model")
    assert "onnx" in info.flavors and info.metadata["spade"]["role"] == "student"
    assert info.signature.inputs.to_dict()[0]["tensor-spec"]["shape"] in ([-1, 3, 64, 64], (-1, 3, 64, 64))
    got = loaded.predict(state.numpy())
    got = got["logits"] if isinstance(got, dict) else np.asarray(got)
    assert got.shape == (3, 1, 64, 64) and np.abs(got - expected).max() < PARITY_BOUND
    assert resolve_model(f"runs:/{run_id}/model", uri).suffix == ".onnx"  # what spade.plan model=runs:/... opens

    assert objects["run"].model_uri == f"runs:/{run_id}/model"  # where train() says the run lives
    assert f"model=runs:/{run_id}/model" in run.data.tags["mlflow.note.content"]
    assert f"logged model     : runs:/{run_id}/model" in run_summary(cfg, {})


def test_an_expert_run_logs_no_model_and_a_failed_export_is_one_warning(tracked_run, tmp_path: Path,
                                                                       caplog: pytest.LogCaptureFixture) -> None:
    """The run record's gate (:func:`~spade.tracking.logged_model.try_log_student_model`), without another
    training run: an expert's config logs nothing even when handed an exportable checkpoint; a student checkpoint
    that cannot be exported (axis-aligned windows) is one warning line and no model, never an error."""
    import logging

    from mlflow import MlflowClient

    from spade.training.checkpoint_paths import best_checkpoint_path
    from spade.tracking.logged_model import is_student_run, try_log_student_model
    from factories import hand_made_checkpoint as _hand_made_checkpoint
    from training_helpers import compose_row

    cfg, objects = tracked_run
    expert = compose_row("cond_expert_L", tmp_path)
    assert is_student_run(cfg) and not is_student_run(expert)
    uri = f"sqlite:///{tmp_path}/mlflow.db"
    client = MlflowClient(tracking_uri=uri)
    experiment_id = client.create_experiment("gate", artifact_location=str(tmp_path / "artifacts"))
    run_id = client.create_run(experiment_id).info.run_id
    assert try_log_student_model(expert, uri, run_id, best_checkpoint_path(objects["trainer"])) is None
    assert try_log_student_model(cfg, uri, run_id, None) is None  # no checkpoint (a run that did not train)

    axis_aligned = _hand_made_checkpoint(tmp_path / "old.ckpt", data={"image_size": [32, 32], "resolution_m": 0.2})
    with caplog.at_level(logging.WARNING, logger="spade.tracking.logged_model"):
        assert try_log_student_model(cfg, uri, run_id, str(axis_aligned)) is None
    (record,) = [r for r in caplog.records if r.name == "spade.tracking.logged_model"]
    assert "not logged on run" in record.getMessage() and "\n" not in record.getMessage()
    assert not client.get_run(run_id).outputs.model_outputs
    assert not client.search_logged_models(experiment_ids=[experiment_id])


def test_an_interrupted_evaluation_is_killed_not_failed(tmp_path) -> None:  # noqa: ANN001
    """spade.evaluate's run, opened by Lightning during the test: Ctrl+C marks it KILLED, an error FAILED."""
    from lightning.pytorch.loggers import MLFlowLogger
    from mlflow import MlflowClient

    from spade.tracking.runs import mark_opened_run_ended

    uri = f"sqlite:///{tmp_path}/mlflow.db"
    statuses = []
    for exc in (KeyboardInterrupt(), ValueError("boom")):
        ml = MLFlowLogger(experiment_name="evaluation", tracking_uri=uri)
        ml.log_metrics({"test/ape_cm": 1.0})  # Lightning opens the run as the test logs
        mark_opened_run_ended([ml], exc)
        statuses.append(MlflowClient(uri).get_run(ml.run_id).info.status)
    assert statuses == ["KILLED", "FAILED"]
    mark_opened_run_ended([], KeyboardInterrupt())  # no MLflow logger: nothing to mark


def _logger(tmp_path: Path, experiment: str = "quickstart"):
    from spade.tracking.logger import MLFlowLogger

    return MLFlowLogger(experiment_name=experiment, tracking_uri=f"sqlite:///{tmp_path}/mlflow.db",
                        artifact_location=str(tmp_path / "artifacts"))


def _steps(client, run_id: str, key: str) -> list[int]:
    return [m.step for m in client.get_metric_history(run_id, key)]


def test_the_logger_holds_references_back_and_logs_test_figures_at_one_step(tmp_path: Path) -> None:
    from lightning.pytorch.loggers import MLFlowLogger as Lightning

    from spade.tracking.predictors import TEST_STEP

    ml = _logger(tmp_path)
    assert isinstance(ml, Lightning) and type(ml).__name__ == "MLFlowLogger"  # the model file's check by name
    ml.log_metrics({"untrained/ape_cm": 104.5, "untrained/baseline/straight/ape_cm": 30.0}, step=0)
    for epoch, step in ((0, 9), (1, 19)):  # training and validation at the global step, margin at step = epoch
        ml.log_metrics({"train/loss": 1.0 / (epoch + 1), "epoch": epoch}, step=step - 5)
        ml.log_metrics({"val/ape_cm": 20.0 - epoch, "epoch": epoch}, step=step)
        ml.log_metrics({"margin/active": 0.5, "margin/value": 0.1}, step=epoch)
    ml.log_metrics({"test/ape_cm": 12.0, "test/baseline/straight/ape_cm": 30.0, "epoch": 2}, step=324)
    client, run_id = ml.experiment, ml.run_id
    metrics = client.get_run(run_id).data.metrics
    assert not [k for k in metrics if k.startswith(("untrained/", "test/baseline/"))], sorted(metrics)
    assert ml.held == {"untrained/ape_cm": 104.5, "untrained/baseline/straight/ape_cm": 30.0,
                       "test/baseline/straight/ape_cm": 30.0}
    assert _steps(client, run_id, "test/ape_cm") == [TEST_STEP]
    assert sorted(_steps(client, run_id, "margin/active")) == [9, 19] == sorted(_steps(client, run_id, "val/ape_cm"))
    assert client.get_run(run_id).data.tags["spade.margin_step"] == "global"
    from spade.tracking.runs import margin_history
    from spade.tracking.progress_picture import epoch_series

    assert [e for e, _ in epoch_series(client, run_id)["margin/active"]] == [0, 1]
    assert margin_history(client, run_id) == [(0, 0.5, 0.1), (1, 0.5, 0.1)]


def test_references_are_child_runs_in_their_colours_and_readers_fold_them_back(tmp_path: Path) -> None:
    from spade.tracking.predictors import COLOUR_TAG, log_predictor_runs, with_predictor_figures
    from spade.utils import palette

    ml = _logger(tmp_path)
    ml.log_metrics({"test/ape_cm": 12.0, "test/baseline/straight/ape_cm": 30.0,
                    "test/baseline/shortest/ape_cm": 25.0, "untrained/ape_cm": 104.5}, step=324)
    client, run_id = ml.experiment, ml.run_id
    client.set_terminated(run_id)
    metrics = {**client.get_run(run_id).data.metrics, **ml.held}
    children = log_predictor_runs(client, run_id, "student", metrics=metrics)
    assert set(children) == {"baseline-straight", "baseline-shortest", "untrained"}
    for name, child in children.items():
        run = client.get_run(child)
        assert run.data.tags[COLOUR_TAG] == palette.predictor_colour(name)
        assert _steps(client, child, "test/ape_cm") == [0]
    assert client.get_run(run_id).data.tags[COLOUR_TAG] == palette.PREDICTION
    colours = {palette.predictor_colour(n) for n in (*children, "student")}
    assert len(colours) == 4  # one colour per predictor kind
    parent = client.get_run(run_id)
    assert "test/baseline/straight/ape_cm" not in parent.data.metrics
    folded = with_predictor_figures(client, [parent])[0]
    assert folded.data.metrics["test/baseline/straight/ape_cm"] == 30.0
    assert folded.data.metrics["untrained/ape_cm"] == 104.5 and folded.data.metrics["test/ape_cm"] == 12.0
    assert folded.data.tags == parent.data.tags and folded.info.run_id == run_id


def test_the_description_opens_with_the_table_and_states_composition_and_wall_time(tmp_path: Path) -> None:
    import json

    from omegaconf import OmegaConf

    from factories import write_synthetic
    from spade.tracking.dataset_inputs import DatasetUse
    from spade.tracking.descriptions import run_description

    root = tmp_path / "tiny" / "test"
    write_synthetic(root, n=12, seed=1)
    manifest = json.loads((root / "manifest.json").read_text())
    total = manifest["num_instances"]
    cfg = OmegaConf.create({"run_name": "quickstart", "tags": {"table": "quickstart", "role": "student",
                                                              "approach": "Cond-DBC", "shape": "L"}})
    metrics = {"test/ape_cm": 12.345, "test/failure_rate": 0.0213, "test/baseline/straight/ape_cm": 30.0,
               "untrained/ape_cm": 104.55}
    text = run_description(cfg, metrics, [DatasetUse(root, "tiny/test", "test", total - 5)], [], seconds=343.2)
    lines = text.splitlines()
    assert lines[0].startswith("| test set ") and "APE cm" in lines[0] and "fail %" in lines[0]
    cells = [c.strip() for c in lines[2].strip().strip("|").split("|")]
    assert cells == ["**this model**", "12.3", "2"], lines[2]  # cm to 0.1, a share in per cent
    assert "untrained" in lines[4]
    assert f"{total - 5} L instances of a {total}-instance L+U set" in text
    assert "Wall time: 5 min 43 s" in text and "half an hour" not in text
    whole = run_description(cfg, metrics, [DatasetUse(root, "tiny/test", "test", total)], [])
    assert f"all {total} instances" in whole


def test_the_logged_model_description_has_the_students_figures_only() -> None:
    from omegaconf import OmegaConf

    from spade.tracking.logged_model import logged_model_description

    cfg = OmegaConf.create({"tags": {"role": "student", "approach": "Cond-DBC", "shape": "L", "scale": "quickstart"}})
    text = logged_model_description(cfg, {"test/ape_cm": 12.3, "test/baseline/straight/ape_cm": 30.0,
                                          "untrained/ape_cm": 104.5}, ("1", "abc", "quickstart"), "runs:/abc/model")
    assert text.startswith("| test set ") and "baseline" not in text.split("\n\n")[0]
    assert "untrained" not in text.split("\n\n")[0] and "runs:/abc/model" in text


def test_one_palette_across_previews_plan_pictures_and_prediction_pictures() -> None:
    from spade.annotation import preview
    from spade.deploy import plan_picture
    from spade.training import visualize
    from spade.utils import palette

    assert preview.PATH_RGB == palette.rgb(palette.DEMONSTRATION)
    assert preview.START_RGB == palette.rgb(palette.ROBOT) and preview.GOAL_RGB == palette.rgb(palette.GOAL)
    legend = {label: colour for label, colour, _ in plan_picture.LEGEND}
    assert legend["plan"] == palette.rgb(palette.PREDICTION) and legend["goal"] == palette.rgb(palette.GOAL)
    assert legend["robot + heading"] == palette.rgb(palette.ROBOT)
    assert visualize.EXTRACTED_COLOUR == palette.PREDICTION
    assert len(set(palette.LABELS.values()) - {palette.ROBOT}) == len(palette.LABELS) - 2  # window = robot only
    assert "--spade-demonstration: " + palette.DEMONSTRATION in palette.CSS_VARIABLES
    with pytest.raises(ValueError):
        palette.rgb("red")


def test_the_description_leads_with_the_deciding_figure_rounded_without_machine_paths_or_repeats(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import re

    from omegaconf import OmegaConf

    from spade.tracking.descriptions import PrerequisiteUse, run_description

    monkeypatch.setenv("SPADE_HOME", str(tmp_path))
    cfg = OmegaConf.create({"run_name": "quickstart", "tags": {"table": "quickstart", "role": "student",
                                                              "approach": "Cond-DBC", "shape": "L"}})
    own = {"planner/ape_cm": 4.875823020935059, "planner/over_20cm_rate": 0.03213, "planner/plausibility_cm": 2.104,
           "planner/commit_rate": 0.8123, "ape_cm": 5.2049, "over_20cm_rate": 0.1, "failure_rate": 0.0213,
           "fid": 49.552631, "hd19": 263.0}
    metrics = {f"test/{k}": v for k, v in own.items()}
    metrics.update({"test/baseline/straight/planner/ape_cm": 30.123456, "test/baseline/straight/fid": 120.98765,
                    "test/baseline/straight/planner/over_20cm_rate": 0.6})
    prerequisites = [PrerequisiteUse("expert", "cond_expert_L", "/home/someone/spade/ckpts/expert-v3.ckpt"),
                     PrerequisiteUse("critic", "cond_expert_L", str(tmp_path / "logs" / "critic.ckpt"))]
    text = run_description(cfg, metrics, [], prerequisites)
    lines = text.splitlines()
    headers = [c.strip() for c in lines[0].strip("|").split("|")]
    # the deciding figure and its tail first, then plausibility and commitment, then the paper's
    assert headers[:5] == ["test set", "plan APE cm", "plan >20cm %", "plaus. cm", "commit %"], headers
    assert headers.index("APE cm") > headers.index("commit %")
    cells = [c.strip() for c in lines[2].strip("|").split("|")]
    assert cells[:5] == ["**this model**", "4.9", "3", "2.1", "81"], cells  # cm to 0.1, shares in whole per cent
    assert "FID" in headers and cells[headers.index("FID")] == "49.55" and cells[headers.index("Hd19 n")] == "263"
    assert not re.search(r"\d\.\d{3,}", text.split("**Verdict.**")[0]), text  # no unrounded figure in the table
    # no path of the writing machine: a path under $SPADE_HOME relative to it, any other by its file name
    assert "/home/" not in text and str(tmp_path) not in text
    assert "checkpoint `expert-v3.ckpt`" in text and "checkpoint `logs/critic.ckpt`" in text
    # the glossary gives each meaning once, the planner's figures under their base figure's meaning
    glossary = next(line for line in lines if line.startswith("Lower is better"))
    assert glossary.startswith("Lower is better, except commit %.")
    assert glossary.count("mean distance between") == 1 and "plan APE cm / APE cm: mean distance" in glossary
    entries = [e.split(":")[0] for e in glossary.split(". ", 1)[1].split("; ")]
    assert len(entries) == len(set(entries)), entries
    assert text.index("| test set") < text.index("**Verdict.**")  # the table is the first thing shown


# -- the closed loop beside the test -------------------------------------------------------------------------------
def _driven(student_ape: float, shortest_ape: float, heading_success: float = 1.0) -> dict[str, float]:
    """A closed loop's figures as ClosedLoopTest logs them: the student's, the baselines' under their prefixes."""
    out = {"closed_loop/episodes": 12.0}
    for prefix, ape, success in (("", student_ape, 1.0), ("baseline/shortest/", shortest_ape, 1.0),
                                 ("baseline/heading/", 20.0, heading_success), ("followed/", 4.5, 1.0)):
        out.update({f"closed_loop/{prefix}ape_cm": ape, f"closed_loop/{prefix}success_rate": success,
                    f"closed_loop/{prefix}mode_switches": 0.7})
    return out


def test_the_baselines_closed_loop_figures_reach_their_child_runs_under_the_students_names(tmp_path: Path) -> None:
    """The drive comes after the test's child runs (spade.train's callback order): the run's record logs them again,
    so one chart of closed_loop/ape_cm shows the student and each baseline driven, at one step."""
    from omegaconf import OmegaConf

    from spade.tracking.callback import RunIdentity, RunRecord
    from spade.tracking.predictors import NOTE_TAG, PARENT_TAG, PREDICTOR_TAG, TEST_STEP

    ml = _logger(tmp_path)
    tags = {"table": "quickstart", "row": "quickstart", "role": "student", "approach": "BC"}
    cfg = OmegaConf.create({"run_name": "quickstart", "tags": tags})
    record = RunRecord(cfg, RunIdentity("quickstart", "quickstart", tags, {}, ("test",), training=False))
    trainer = SimpleNamespace(is_global_zero=True, loggers=[ml], datamodule=None)
    ml.log_metrics({k: v for k, v in METRICS.items() if k.startswith("test/")}, step=324)
    record.on_test_end(trainer, None)  # the test's child runs, before the drive
    client, run_id = ml.experiment, ml.run_id
    ml.log_metrics(_driven(12.1, 15.3), step=324)  # ClosedLoopTest, at the test's end too
    record.finish(trainer, ml)

    children = {r.data.tags[PREDICTOR_TAG]: r for r in client.search_runs(
        [client.get_run(run_id).info.experiment_id], filter_string=f"tags.`{PARENT_TAG}` = '{run_id}'")}
    assert sorted(children) == ["baseline-heading", "baseline-shortest", "baseline-straight"]  # none doubled
    parent = client.get_run(run_id).data.metrics
    shortest, heading = children["baseline-shortest"].data.metrics, children["baseline-heading"].data.metrics
    assert shortest["closed_loop/ape_cm"] == parent["closed_loop/baseline/shortest/ape_cm"] == 15.3
    assert heading["closed_loop/ape_cm"] == 20.0 and heading["closed_loop/mode_switches"] == 0.7
    assert parent["closed_loop/ape_cm"] == 12.1 and heading["test/ape_cm"] == 12.0  # the test's figures kept
    assert not [k for k in children["baseline-straight"].data.metrics if k.startswith("closed_loop/")]  # not driven
    assert not [k for c in children.values() for k in c.data.metrics if "/baseline/" in k or "followed" in k]
    for run in (run_id, children["baseline-shortest"].info.run_id):  # one x for the student and its baselines
        assert _steps(client, run, "closed_loop/ape_cm") == [TEST_STEP]
    assert "closed-loop scenarios" in children["baseline-shortest"].data.tags[NOTE_TAG]
    description = client.get_run(run_id).data.tags[NOTE_TAG]
    assert "**Closed loop.** Success 100 %, APE 12.1 cm, 0.70 mode switches per scenario; this model beats the " \
           "Nav2-like shortest path (15.3 cm) and the heading template (20.0 cm)" in description


@pytest.mark.parametrize("student, shortest, heading_success, verdict", [
    (12.1, 15.3, 1.0, "this model beats the Nav2-like shortest path (15.3 cm) and the heading template (20.0 cm)"),
    (18.0, 15.3, 1.0, "this model beats the heading template (20.0 cm) but loses to the Nav2-like shortest path "
                      "(15.3 cm)"),
    (22.0, 15.3, 0.9, "this model is mixed against the heading template (20.0 cm, success 90 %) but loses to the "
                      "Nav2-like shortest path (15.3 cm)"),
])
def test_the_description_gives_the_closed_loops_verdict_either_way(student: float, shortest: float,
                                                                    heading_success: float, verdict: str) -> None:
    from omegaconf import OmegaConf

    from spade.tracking.descriptions import run_description

    cfg = OmegaConf.create({"run_name": "quickstart", "tags": {"table": "quickstart", "role": "student"}})
    text = run_description(cfg, {**METRICS, **_driven(student, shortest, heading_success)}, [], [])
    line = next(p for p in text.split("\n\n") if p.startswith("**Closed loop.**"))
    assert verdict in " ".join(line.split()), line
    assert line.endswith("the demonstration followed drives at 4.5 cm (what the follower itself costs).")
    assert text.index("**Verdict.**") < text.index("**Closed loop.**")
    assert "**Closed loop.**" not in run_description(cfg, METRICS, [], [])  # not driven: no line
