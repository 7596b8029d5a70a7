"""The MLflow UI as a person meets it: the smoke run, then Chromium on the URLs the run printed.

The ``smoke`` experiment trains into a temporary SPADE_HOME (SQLite store); ``mlflow server`` serves that store
on 127.0.0.1 (a free port, which the run is told through ``SPADE_MLFLOW_UI_URL`` so that the URLs it prints point
there); Debian's chromium, driven by Playwright, opens the experiment URL and must land on the runs table with the
run, its Dataset and metric columns and its baselines' child runs as lines of their own, then the run URL (metrics,
description, datasets) and one of its prediction pictures. A fresh browser profile also clicks the experiment in
the experiments list: MLflow 3.17 opens it on the GenAI overview until the sidebar's switch says "Model training"
(what the printed lines ask, once per browser), then on its runs. Screenshots go to ``test-artifacts/`` (kept by CI).

A real tiny quickstart run (``+experiment=quickstart scale=tiny``, the shipped expert) read at a glance: its logged
model's metrics are the student's ``test/*`` (and ``model/*``), no ``untrained/*``, no baseline; the parent run holds
no ``untrained/*`` and no ``test/baseline/*`` (those are the child runs'); the description opens with the figures'
table, visible without "Show more"; the runs table lists the run with its baselines and untrained model as child
runs, with the test-metric columns in view. Its screenshots go to ``test-artifacts/mlflow_surfaces/``;
``SPADE_UPDATE_DOCS_PICTURES=1`` also copies the runs view to ``docs/assets/mlflow-runs-view.png`` (the picture of
docs/reference/tracking.md).
"""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

import pytest

from browser_support import ARTIFACTS, browser_page, chromium_path, screenshot
from mlflow_server_support import REPO, FAST, free_port, mlflow_server, printed, served_home, wait_healthy  # noqa: F401


def _check_ui(experiment_url: str, run_url: str, run_name: str, dataset: str, described: str, picture: str,
              shots: str, prerequisite: str | None = None, experiment: str = "smoke",
              children: tuple[str, ...] = ()) -> None:
    """What a person must see: the runs table with the run and the deciding figure's column, its predictors
    (``children``: the baselines' and the untrained model's child runs) listed under it; the run page with its
    description (holding ``described``), metrics and datasets; a prediction picture through the Artifacts tab; and,
    in a fresh browser profile, the experiment clicked in the experiments list opening on its runs once the sidebar's
    switch says "Model training" (what the printed lines ask: :data:`spade.tracking.links.SWITCH_HINT`)."""
    run_id = re.search(r"/runs/([0-9a-f]{32})\?", run_url).group(1)
    _check_experiments_list(experiment_url.split("/#/")[0], experiment, run_id, run_name, shots)
    with browser_page(width=1800) as page:  # the runs table draws only the columns in view
        page.set_default_timeout(90_000)
        # 1. The experiment URL lands on the runs table (not MLflow 3's GenAI overview).
        page.goto(experiment_url)
        page.locator(f'a[href*="/runs/{run_id}"]', has_text=run_name).first.wait_for(state="visible")
        # the deciding figure's column first (its rounded tag); the Dataset column sits at the view's right end,
        # which the table draws only when scrolled to: the run page below shows the run's datasets
        page.get_by_role("columnheader", name="planner APE", exact=True).first.wait_for(state="visible")
        assert "/runs" in page.url and "/traces" not in page.url and "/overview" not in page.url, page.url
        for child in children:  # SPADE's view shows the run expanded: its predictors are rows under it
            page.get_by_text(child, exact=True).first.wait_for(state="visible")
        screenshot(page, f"{shots}_runs.png")
        # 2. The run URL: its description, its test metrics, its dataset inputs.
        page.goto(run_url)
        page.get_by_text(described).first.wait_for(state="visible")
        # a finite test metric (the UI leaves NaN values out of the run's metric list: a briefly trained student's
        # paper APE is NaN when no path could be extracted; Hd19 and the planner's APE are always defined)
        page.get_by_text("test/hd19", exact=True).first.wait_for(state="visible")
        page.get_by_text(f"{dataset} (train split)").first.wait_for(state="attached")
        screenshot(page, f"{shots}_run.png")
        if prerequisite:  # the description links the prerequisite's run (the UI opens it in a new tab)
            if page.get_by_text("Show more").count():
                page.get_by_text("Show more").first.click()
            with page.context.expect_page() as opened:
                page.get_by_role("link", name=prerequisite).first.click()
            opened.value.get_by_text("Description").first.wait_for(state="visible")
            assert re.search(r"/runs/[0-9a-f]{32}\?", opened.value.url) and run_id not in opened.value.url
            opened.value.get_by_text(prerequisite, exact=True).first.wait_for(state="visible")
            opened.value.close()
        # 3. A prediction picture, reached as a person would: Artifacts tab, predictions folder, the file.
        page.get_by_role("tab", name="Artifacts").click()
        page.get_by_text("predictions", exact=True).first.click()
        page.get_by_text(Path(picture).name, exact=True).first.click()
        page.wait_for_function(
            "() => [...document.images].some(i => i.src.startsWith('blob:') && i.complete && i.naturalWidth > 64)")
        screenshot(page, f"{shots}_picture.png")


def _check_experiments_list(base: str, experiment: str, run_id: str, run_name: str, shots: str) -> None:
    """A fresh browser profile clicks the experiment in the experiments list. MLflow 3.17 picks the page by the
    sidebar's GenAI / Model training switch (the URL's ``workflowType``, else the browser's stored choice, else
    GenAI), not by the experiment's ``mlflow.experimentKind`` tag: the first click shows what an untouched browser
    gets (screenshot, not asserted: that is MLflow's choice); after the one click SPADE's closing lines ask for, the
    experiment opens on its runs table, and stays so for the browser."""
    with browser_page(width=1600, height=1000) as page:
        page.set_default_timeout(90_000)
        link = page.locator('[data-testid="experiment-list-item-link"]', has_text=experiment).first
        page.goto(f"{base}/#/experiments")
        link.wait_for(state="visible")
        link.click()
        page.wait_for_timeout(3000)
        screenshot(page, f"{shots}_list_click_untouched.png")
        page.goto(f"{base}/#/experiments")
        page.get_by_text("Model training", exact=True).first.click()  # the sidebar's switch, once
        link.wait_for(state="visible")
        link.click()
        page.locator(f'a[href*="/runs/{run_id}"]', has_text=run_name).first.wait_for(state="visible")
        page.get_by_role("columnheader", name="Run Name").first.wait_for(state="visible")
        assert "/overview" not in page.url and "/traces" not in page.url, page.url
        assert page.evaluate("() => localStorage.getItem('mlflow.workflowType_v1')") == '"machine_learning"'
        screenshot(page, f"{shots}_list_click.png")


@pytest.mark.slow  # an mlflow server and a browser; the URLs, tags, inputs and descriptions in-process: below
def test_mlflow_ui_shows_a_spade_run_from_the_printed_urls(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A run recorded by SPADE's tracking code (no training: seconds), then the browser on the URLs it prints."""
    chromium_path()
    pytest.importorskip("playwright.sync_api")
    import numpy as np
    from omegaconf import OmegaConf

    from factories import write_synthetic
    from spade.tracking.dataset_inputs import DatasetUse, log_dataset_inputs
    from spade.tracking.descriptions import run_description
    from spade.tracking.links import ui_lines
    from spade.tracking.figure_tags import figure_tags
    from spade.tracking.predictors import log_predictor_runs
    from spade.tracking.runs import bind_experiment

    port = free_port()
    base = f"http://127.0.0.1:{port}"
    monkeypatch.setenv("SPADE_MLFLOW_UI_URL", base)
    store = f"sqlite:///{tmp_path}/mlflow.db"
    for name, seed in (("lshape", 0), ("test", 1)):
        write_synthetic(tmp_path / "tiny" / name, n=9, seed=seed)
    ml = _logger(tmp_path, "smoke")
    bind_experiment(ml)  # creates the store before the server opens it
    with mlflow_server(store, port, tmp_path) as server:  # boots while the run is recorded
        client, run_id = ml.experiment, ml.run_id
        client.set_tag(run_id, "mlflow.runName", "ui_check")
        metrics = {"test/ape_cm": 12.5, "test/hd19": 2.0, "test/failure_rate": 0.1, "model/params": 118165.0,
                   "test/planner/ape_cm": 11.0, "test/planner/over_20cm_rate": 0.1,
                   "test/baseline/straight/ape_cm": 30.0}
        ml.log_metrics(metrics)
        for key, value in figure_tags(metrics).items():  # the rounded figures the runs view shows, as spade.train
            client.set_tag(run_id, key, value)
        uses = [DatasetUse(tmp_path / "tiny/lshape", "tiny/lshape (train split)", "training", 6),
                DatasetUse(tmp_path / "tiny/test", "tiny/test", "test", 9)]
        log_dataset_inputs(client, run_id, uses)
        picture = "predictions/test_worst.png"
        client.log_image(run_id, np.full((96, 160, 3), (40, 200, 60), dtype=np.uint8), artifact_file=picture)
        cfg = OmegaConf.create({"run_name": "ui_check", "tags": {"table": "smoke", "role": "student"}})
        client.set_tag(run_id, "mlflow.note.content", run_description(cfg, metrics, uses, []))
        client.set_terminated(run_id)
        log_predictor_runs(client, run_id, "student")  # its baselines as child runs, as spade.train logs them
        experiment_id = client.get_run(run_id).info.experiment_id
        _, run_line, experiment_line, _ = ui_lines(store, experiment_id, run_id)
        wait_healthy(base, server, tmp_path / "server.log", timeout=180)
        _check_ui(experiment_line.split()[-1], run_line.split()[-1], "ui_check", "tiny/lshape", "Tested on", picture,
                  "mlflow_ui_recorded", children=("ui_check/baseline-straight",))


@pytest.mark.slow  # trains the smoke experiment: about a minute on a quiet 2-core machine, several when shared
def test_mlflow_ui_opens_the_smoke_run_from_the_urls_it_printed(served_home) -> None:  # noqa: ANN001
    store, base, client = served_home.store, served_home.base, served_home.client
    port = int(base.rsplit(":", 1)[1])
    out = served_home.train("+experiment=smoke", *FAST)  # the server boots while the run trains
    assert f"mlflow ui --backend-store-uri {store} --port {port}" in out
    experiment_url, run_url = printed(out, "experiment's runs"), printed(out, "this run")
    assert experiment_url.startswith(base) and "workflowType=machine_learning" in experiment_url
    assert run_url.startswith(base) and "workflowType=machine_learning" in run_url
    run_id = re.search(r"/runs/([0-9a-f]{32})\?", run_url).group(1)
    pictures = sorted(a.path for a in client.list_artifacts(run_id, "predictions") if a.path.endswith(".png"))
    assert pictures, "the run logged no prediction picture"
    assert client.get_run(run_id).info.run_name == "smoke"
    served_home.wait_healthy()
    _check_ui(experiment_url, run_url, "smoke", "tiny/lshape", "Prerequisites: expert from", pictures[0],
              "mlflow_ui_smoke", prerequisite="cond_expert_L",
              children=("smoke/baseline-straight", "smoke/baseline-shortest", "smoke/baseline-heading"))


# -- the pieces, without training or a browser (fast) ---------------------------------------------------------
def test_printed_urls_open_runs_views(monkeypatch: pytest.MonkeyPatch) -> None:
    from spade.tracking.links import ui_lines

    monkeypatch.delenv("SPADE_MLFLOW_UI_URL", raising=False)
    command, run, experiment, switch = ui_lines("sqlite:////x/mlflow.db", "3", "ab12")
    assert command.endswith("mlflow ui --backend-store-uri sqlite:////x/mlflow.db")
    assert '"Model training"' in switch  # MLflow 3.17 opens an experiment by the sidebar's switch, not its tags
    assert run.split()[-1] == "http://127.0.0.1:5000/#/experiments/3/runs/ab12?workflowType=machine_learning"
    assert experiment.split()[-1] == ("http://127.0.0.1:5000/#/experiments/3/runs?viewStateShareKey=spade"
                                      "&workflowType=machine_learning")
    server = ui_lines("http://tracking:8080/", "3")
    assert server[0].endswith("at:  http://tracking:8080") and "http://tracking:8080/#/experiments/3/runs?" in server[1]
    monkeypatch.setenv("SPADE_MLFLOW_UI_URL", "http://127.0.0.1:6001")
    assert ui_lines("sqlite:////x/mlflow.db", "3")[0].endswith("--port 6001")
    monkeypatch.setenv("SPADE_MLFLOW_UI_URL", "127.0.0.1:6001")
    with pytest.raises(ValueError, match="must start with http"):
        ui_lines("sqlite:////x/mlflow.db", "3")


def _logger(tmp_path: Path, experiment: str):
    from lightning.pytorch.loggers import MLFlowLogger

    return MLFlowLogger(experiment_name=experiment, tracking_uri=f"sqlite:///{tmp_path}/mlflow.db",
                        artifact_location=str(tmp_path / "artifacts"))


def test_experiments_are_tagged_as_training_with_a_description(tmp_path: Path) -> None:
    import json

    from spade.tracking.experiment_tags import KIND_TAG, NOTE_TAG, VIEW_TAG
    from spade.tracking.runs import bind_experiment

    ml = _logger(tmp_path, "table2")
    bind_experiment(ml)
    client = ml.experiment
    tags = client.get_experiment(ml.experiment_id).tags
    assert tags[KIND_TAG] == "custom_model_development"
    assert "Table 2" in tags[NOTE_TAG] and "python -m spade.train +experiment=ablation_finetune" in tags[NOTE_TAG]
    assert "python -m spade.report table=table2" in tags[NOTE_TAG] and "t2_bc_finetune_U" in tags[NOTE_TAG]
    assert json.loads(tags[VIEW_TAG])["selectedColumns"][0] == "tags.`planner APE`"  # the deciding figure
    # Experiments made before SPADE tagged them get the tags; a description a person wrote stays.
    old = client.create_experiment("quickstart", tags={NOTE_TAG: "my own notes"})
    bind_experiment(_logger(tmp_path, "quickstart"))
    tags = client.get_experiment(old).tags
    assert tags[KIND_TAG] == "custom_model_development" and tags[NOTE_TAG] == "my own notes" and VIEW_TAG in tags
    bind_experiment(_logger(tmp_path, "sweep_conddbc_lambda"))
    note = client.get_experiment_by_name("sweep_conddbc_lambda").tags[NOTE_TAG]
    assert "python -m spade.train --config-dir sweeps +search=conddbc_lambda" in note


def test_an_experiment_a_parallel_job_creates_first_is_bound_and_tagged(tmp_path: Path,
                                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    """Two sweep jobs into an empty store: both find the experiment absent, the other job creates it first, this
    job's create fails; the run still opens (one run, in that experiment) and the experiment is tagged."""
    from mlflow import MlflowClient

    from spade.tracking.experiment_tags import KIND_TAG, NOTE_TAG, VIEW_TAG
    from spade.tracking.runs import bind_experiment

    create = MlflowClient.create_experiment

    def created_first_by_another_job(self, name, *args, **kwargs):
        monkeypatch.setattr(MlflowClient, "create_experiment", create)
        create(MlflowClient(tracking_uri=f"sqlite:///{tmp_path}/mlflow.db"), name)  # the other job's
        return create(self, name, *args, **kwargs)  # fails: the name exists now

    monkeypatch.setattr(MlflowClient, "create_experiment", created_first_by_another_job)
    ml = _logger(tmp_path, "table1")
    bind_experiment(ml)
    experiment = ml.experiment.get_experiment_by_name("table1")
    assert ml.experiment_id == experiment.experiment_id
    assert experiment.tags[KIND_TAG] == "custom_model_development" and NOTE_TAG in experiment.tags
    assert VIEW_TAG in experiment.tags
    assert [r.info.run_id for r in ml.experiment.search_runs([experiment.experiment_id])] == [ml.run_id]


def test_a_tag_a_parallel_job_writes_at_the_same_moment_is_not_an_error(tmp_path: Path,
                                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    """Two sweep jobs tag the new experiment together: the other job's insert lands between this job's look-up and
    insert, whose write fails on the unique key (CI saw it through ``mlflow server``). The run still opens and
    the experiment ends with SPADE's tags; a failure that leaves the tag unset still raises."""
    from mlflow import MlflowClient
    from mlflow.exceptions import MlflowException

    from spade.tracking.experiment_tags import KIND_TAG, NOTE_TAG, VIEW_TAG
    from spade.tracking.runs import bind_experiment

    set_tag = MlflowClient.set_experiment_tag
    raced: list[str] = []

    def written_first_by_another_job(self, experiment_id, key, value):
        if key not in raced:  # the other job wins each tag once; its note is its own
            raced.append(key)
            set_tag(self, experiment_id, key, "the other job's note" if key == NOTE_TAG else value)
            raise MlflowException("UNIQUE constraint failed: experiment_tags.key, experiment_tags.experiment_id")
        return set_tag(self, experiment_id, key, value)

    monkeypatch.setattr(MlflowClient, "set_experiment_tag", written_first_by_another_job)
    ml = _logger(tmp_path, "table1")
    bind_experiment(ml)
    tags = ml.experiment.get_experiment(ml.experiment_id).tags
    assert raced == [KIND_TAG, NOTE_TAG, VIEW_TAG]
    assert tags[KIND_TAG] == "custom_model_development" and tags[NOTE_TAG] == "the other job's note"
    assert VIEW_TAG in tags

    def failing(self, experiment_id, key, value):
        raise MlflowException("the store is read-only")

    monkeypatch.setattr(MlflowClient, "set_experiment_tag", failing)
    with pytest.raises(MlflowException, match="read-only"):
        bind_experiment(_logger(tmp_path, "table2"))


def test_datasets_are_run_inputs_with_fingerprint_source_context_and_profile(tmp_path: Path) -> None:
    import json
    from types import SimpleNamespace

    from factories import write_synthetic
    from spade.tracking.dataset_inputs import dataset_fingerprint, dataset_uses, log_dataset_inputs

    for name, seed in (("lshape", 0), ("test", 1), ("lshape_again", 0)):
        write_synthetic(tmp_path / "tiny" / name, n=9, seed=seed)
    train, test = tmp_path / "tiny" / "lshape", tmp_path / "tiny" / "test"
    assert dataset_fingerprint(train) == dataset_fingerprint(tmp_path / "tiny" / "lshape_again")  # same bytes
    assert dataset_fingerprint(train) != dataset_fingerprint(test)
    datamodule = SimpleNamespace(train_dir=train, test_dir=test, train_set=list(range(6)), val_set=list(range(3)),
                                 test_set=list(range(9)))
    ml = _logger(tmp_path, "smoke")
    log_dataset_inputs(ml.experiment, ml.run_id, dataset_uses(datamodule))
    inputs = ml.experiment.get_run(ml.run_id).inputs.dataset_inputs
    got = {d.dataset.name: (d.dataset.digest, json.loads(d.dataset.source)["uri"], d.tags[0].value,
                            json.loads(d.dataset.profile)) for d in inputs}
    assert set(got) == {"tiny/lshape (train split)", "tiny/lshape (validation split)", "tiny/test"}
    digest, source, context, profile = got["tiny/lshape (train split)"]
    assert (digest, source, context) == (dataset_fingerprint(train), str(train), "training")
    assert profile["instances"] == 9 and profile["instances_used"] == 6 and profile["shapes"] == ["L", "U"]
    assert got["tiny/lshape (validation split)"][2:4] == ("validation", {**profile, "instances_used": 3})
    assert got["tiny/test"][0] == dataset_fingerprint(test) and got["tiny/test"][2] == "test"
    assert {d.dataset.source_type for d in inputs} == {"local"}  # the UI's source column reads "local"
    with pytest.raises(FileNotFoundError, match="no dataset manifest"):
        dataset_fingerprint(tmp_path / "nothing")


def test_a_dataset_a_parallel_job_logs_at_the_same_moment_is_linked_not_an_error(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Two sweep jobs test on one set and finish together: the other job's dataset row lands between this job's
    look-up and insert, which fails on the unique key (CI saw it through ``mlflow server``). The run ends up
    linked to the one shared row; any other failure still raises."""
    from types import SimpleNamespace

    from mlflow import MlflowClient
    from mlflow.exceptions import MlflowException

    from factories import write_synthetic
    from spade.tracking.dataset_inputs import dataset_uses, log_dataset_inputs

    for name, seed in (("lshape", 0), ("test", 1)):
        write_synthetic(tmp_path / "tiny" / name, n=9, seed=seed)
    datamodule = SimpleNamespace(train_dir=tmp_path / "tiny/lshape", test_dir=tmp_path / "tiny/test",
                                 train_set=list(range(6)), val_set=list(range(3)), test_set=list(range(9)))
    other, this = _logger(tmp_path, "table1"), _logger(tmp_path, "table1")
    other_run, this_run = other.run_id, this.run_id  # both runs open before either logs
    log_inputs = MlflowClient.log_inputs
    calls: list[str] = []

    def raced_by_the_other_job(self, run_id, datasets=None, models=None):
        calls.append(run_id)
        if len(calls) == 1:  # the other job's rows commit first; this job's insert then breaks the unique key
            log_inputs(self, other_run, datasets=datasets)
            raise MlflowException("(sqlite3.IntegrityError) UNIQUE constraint failed: datasets.experiment_id, "
                                  "datasets.name, datasets.digest")
        return log_inputs(self, run_id, datasets=datasets, models=models)

    monkeypatch.setattr(MlflowClient, "log_inputs", raced_by_the_other_job)
    log_dataset_inputs(this.experiment, this_run, dataset_uses(datamodule))
    assert calls == [this_run, this_run]
    names = {run: sorted(d.dataset.name for d in this.experiment.get_run(run).inputs.dataset_inputs)
             for run in (this_run, other_run)}
    assert names[this_run] == names[other_run] == ["tiny/lshape (train split)", "tiny/lshape (validation split)",
                                                    "tiny/test"]
    experiment_id = this.experiment.get_run(this_run).info.experiment_id
    shared = {(d.dataset.name, d.dataset.digest) for run in (this_run, other_run)
              for d in this.experiment.get_run(run).inputs.dataset_inputs}
    assert len(shared) == 3 and experiment_id == this.experiment.get_run(other_run).info.experiment_id

    def failing(self, run_id, datasets=None, models=None):
        raise MlflowException("the store is read-only")

    monkeypatch.setattr(MlflowClient, "log_inputs", failing)
    with pytest.raises(MlflowException, match="read-only"):
        log_dataset_inputs(this.experiment, this_run, dataset_uses(datamodule))


def test_run_description_links_prerequisites_and_puts_figures_next_to_baselines(tmp_path: Path) -> None:
    from omegaconf import OmegaConf

    from spade.tracking.dataset_inputs import DatasetUse
    from spade.tracking.descriptions import prerequisite_uses, run_description

    ml = _logger(tmp_path, "table1")
    client = ml.experiment
    client.set_tag(ml.run_id, "mlflow.runName", "cond_expert_L")
    client.create_registered_model("spade-cond_expert-L-tiny-abc")
    client.create_model_version("spade-cond_expert-L-tiny-abc", source="x", run_id=ml.run_id)
    cache = tmp_path / "registry-cache"
    cfg = OmegaConf.create({
        "run_name": "t1_small_conddbc_L", "paths": {"registry_cache_dir": str(cache)},
        "model": {"margin": {"expert_ckpt": str(cache / "spade-cond_expert-L-tiny-abc" / "v1" / "best" / "e.ckpt")}},
        "requires": {"expert": {"experiment": "cond_expert_L", "target": "model.margin.expert_ckpt"}},
        "scale": {"name": "tiny"},
        "tags": {"table": "table1", "role": "student", "approach": "Cond-DBC", "size": "small", "shape": "L",
                 "scale": "tiny"}})
    prerequisites = prerequisite_uses(cfg, client)
    experiment_id = client.get_run(ml.run_id).info.experiment_id
    assert prerequisites[0].run_link == f"[cond_expert_L](#/experiments/{experiment_id}/runs/{ml.run_id}" \
                                        "?workflowType=machine_learning)"
    metrics = {"test/ape_cm": 4.5, "test/hd19": 3.0, "test/failure_rate": 0.02, "model/params": 118165.0,
               "test/baseline/straight/ape_cm": 30.25, "test/baseline/straight/failure_rate": 0.0,
               "untrained/ape_cm": 190.0}
    uses = [DatasetUse(tmp_path / "tiny/lshape", "tiny/lshape (train split)", "training", 160),
            DatasetUse(tmp_path / "tiny/test", "tiny/test", "test", 43)]
    text = run_description(cfg, metrics, uses, prerequisites, ["predictions/test_worst.png"])
    # the table first (the UI shows it without "Show more"), units in its headers, shares in per cent
    assert text.startswith("| test set ") and "APE cm" in text.splitlines()[0]
    assert "**t1_small_conddbc_L**: Cond-DBC student (size small, 118k parameters), L-shape paths" in text
    assert "Trained on `tiny/lshape` (160 instances)" in text and "Tested on `tiny/test`: 43 instances." in text
    assert "registered model `spade-cond_expert-L-tiny-abc v1`, run [cond_expert_L](#/experiments/" in text
    assert "Regenerate: `python -m spade.train +experiment=t1_small_conddbc_L scale=tiny`" in text
    # aligned columns: labels left, figures right, every line of the table as wide as its header; no-break spaces
    # before each figure, which MLflow's HTML does not collapse (else the cells run together)
    assert "| **this model**     |    \u00a0\u00a04.5 |      \u00a0\u00a02 |      \u00a0\u00a03 |" in text
    plain = text.replace("\u00a0", " ")
    assert "| baseline: straight |     30.2 |        0 |      n/a |" in plain
    assert "| untrained          |    190.0 |" in plain
    table = [line for line in text.splitlines() if line.startswith("|")]
    assert len({len(line) for line in table}) == 1 and table[0].startswith("| test set ")
    assert "APE cm: mean distance between" in text and "Hd19 n: instances whose Hausdorff distance" in text
    assert "fail %: share of instances" in text and ">20cm %" not in text  # the glossary: the columns shown
    assert "`predictions/test_worst.png`" in text
    linked = run_description(cfg, metrics, uses, prerequisites, ["predictions/test_worst.png"], ("5", "ab12"))
    assert ("[predictions/test_worst.png](#/experiments/5/runs/ab12/artifacts/predictions/test_worst.png"
            "?workflowType=machine_learning)") in linked
    assert "No test figures" in run_description(cfg, {}, [], [])


def test_report_logs_its_chart_into_the_rows_runs_and_prints_their_urls(tmp_path: Path) -> None:
    from mlflow import MlflowClient

    from spade.tracking.tables import TABLES
    from spade.experiments.reporting import build_report

    uri = f"sqlite:///{tmp_path}/mlflow.db"
    client = MlflowClient(tracking_uri=uri)
    experiment = client.create_experiment("table3", artifact_location=str(tmp_path / "artifacts"))
    runs = {}
    for row in TABLES["table3"].rows:
        run = client.create_run(experiment, run_name=row, tags={"scale": "tiny"})
        client.log_metric(run.info.run_id, "test/ape_cm", 5.0)
        if row == "t3_bc_scratch_U":  # a SPADE training run; the other one was made by another tool
            client.log_text(run.info.run_id, "x: 1", "config/train.yaml")
        client.set_terminated(run.info.run_id)
        runs[row] = run.info.run_id
    text = build_report(TABLES["table3"], uri, tmp_path / "reports", log_to_runs=True).text
    assert f"#/experiments/{experiment}/runs?viewStateShareKey=spade&workflowType=machine_learning" in text
    assert f"#/experiments/{experiment}/runs/{runs['t3_bc_scratch_U']}?workflowType=machine_learning" in text
    logged = {a.path for a in client.list_artifacts(runs["t3_bc_scratch_U"], "report")}
    assert logged == {"report/table3.png", "report/table3.md"}
    assert not client.list_artifacts(runs["t3_augbc_pretrained_expert_U"], "report")
    assert client.get_experiment(experiment).tags["mlflow.experimentKind"] == "custom_model_development"


DOCS_PICTURE = REPO / "docs" / "assets" / "mlflow-runs-view.png"


CHILDREN = ("quickstart/baseline-straight", "quickstart/baseline-shortest", "quickstart/baseline-heading",
            "quickstart/untrained")


def _close_assistant(page) -> None:
    """MLflow 3.17 opens its Assistant panel on a browser's first visit, over a quarter of the page: close it
    with its X, as a person would (the browser then keeps it closed)."""
    close = page.locator('[data-component-id="mlflow.assistant.chat_panel.close"]').first
    try:
        close.wait_for(state="visible", timeout=8000)
    except Exception:  # noqa: BLE001 - closed already, or an MLflow without the panel
        return
    close.click()
    close.wait_for(state="hidden")


def _in_view(page, locator) -> bool:
    """Whether the element is drawn inside the 1600x1000 viewport and on top there (not below a fold, not
    scrolled off, not under a panel)."""
    box = locator.bounding_box()
    size = page.viewport_size
    if not box or box["x"] < 0 or box["y"] < 0 or box["x"] + box["width"] > size["width"] \
            or box["y"] + box["height"] > size["height"]:
        return False
    return locator.evaluate("(e, [x, y]) => { const top = document.elementFromPoint(x, y); "
                            "return !!top && (e.contains(top) || top.contains(e)); }",
                            [box["x"] + box["width"] / 2, box["y"] + box["height"] / 2])


@pytest.mark.slow  # trains the quickstart at scale=tiny (about a minute on a quiet 2-core machine), a server, a browser
@pytest.mark.timeout(1200)
def test_the_quickstart_run_its_model_and_the_runs_view_read_at_a_glance(served_home) -> None:  # noqa: ANN001
    shots = ARTIFACTS / "mlflow_surfaces"
    shutil.rmtree(shots, ignore_errors=True)
    print(f"\nscreenshots: {shots.resolve()}")
    client, base = served_home.client, served_home.base
    out = served_home.train("+experiment=quickstart", "scale=tiny", *FAST)  # the server boots while the run trains
    run_url, experiment_url = printed(out, "this run"), printed(out, "experiment's runs")
    run_id = re.search(r"/runs/([0-9a-f]{32})\?", run_url).group(1)
    # the console wraps a long log line at 120 columns (spade.utils.console): the words may sit on two lines
    model_id = re.search(r"logged the student as\s+runs:/\w+/model\s+\(models:/(m-[0-9a-f]+)\)", out)
    assert model_id, f"the run logged no model:\n{out[-3000:]}"
    model_id = model_id.group(1)

    # -- the store: what the pages below must show
    run = client.get_run(run_id)
    parent = sorted(run.data.metrics)
    assert "test/ape_cm" in parent and "test/planner/ape_cm" in parent
    assert not [k for k in parent if k.startswith(("untrained/", "test/baseline/"))], parent
    model_metrics = sorted({m.key for m in client.get_logged_model(model_id).metrics})
    assert "test/ape_cm" in model_metrics, model_metrics
    assert all(k.startswith(("test/", "model/")) for k in model_metrics), model_metrics
    assert not [k for k in model_metrics if k.startswith("untrained/") or "baseline" in k], model_metrics
    note = run.data.tags["mlflow.note.content"].splitlines()
    assert note[0].startswith("| test set ") and "APE cm" in note[0] and "this model" in note[2], note[:3]
    children = {r.info.run_name for r in client.search_runs(
        [run.info.experiment_id], f"tags.mlflow.parentRunId = '{run_id}'")}
    assert children == set(CHILDREN), children
    untrained = client.search_runs([run.info.experiment_id], "attributes.run_name = 'quickstart/untrained'")[0]
    assert "test/ape_cm" in untrained.data.metrics  # the untrained figures: on its child run, by the model's names

    served_home.wait_healthy()
    picture = _check_pages(base, run_url, experiment_url, run.info.experiment_id, model_id, len(model_metrics))
    if os.environ.get("SPADE_UPDATE_DOCS_PICTURES") == "1":
        DOCS_PICTURE.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(picture, DOCS_PICTURE)
    for name in ("1_run", "2_run_model_metrics", "3_model", "4_runs_view"):
        assert (shots / f"{name}.png").stat().st_size > 20_000, name  # a drawn page, not a blank one


def _check_pages(base: str, run_url: str, experiment_url: str, experiment_id: str, model_id: str,
                 n_metrics: int) -> Path:
    """The run page, the logged model page and the runs view as a person sees them at 1600x1000; screenshots
    under ``test-artifacts/mlflow_surfaces/``; returns the runs view's."""
    with browser_page(width=1600, height=1000) as page:
        page.set_default_timeout(90_000)
        # 1. the run page: the description opens with the table, in view without "Show more"
        page.goto(run_url)
        page.get_by_text("Description", exact=True).first.wait_for(state="visible")
        _close_assistant(page)
        header = page.get_by_role("columnheader", name="APE cm", exact=True).first
        header.wait_for(state="visible")
        header.scroll_into_view_if_needed()
        assert _in_view(page, header)
        row = page.get_by_role("row").filter(has_text="this model").first
        assert row.is_visible() and re.search(r"\d+\.\d", row.inner_text()), row.inner_text()
        body = page.inner_text("body")
        assert "untrained/" not in body and "test/baseline/" not in body
        screenshot(page, "mlflow_surfaces/1_run.png")
        page.get_by_role("tab", name="Model metrics").click()
        page.wait_for_timeout(3000)
        screenshot(page, "mlflow_surfaces/2_run_model_metrics.png")

        # 2. the logged model: the student's test figures, its description's table first
        page.goto(f"{base}/#/experiments/{experiment_id}/models/{model_id}?workflowType=machine_learning")
        page.get_by_text(f"Metrics ({n_metrics})").first.wait_for(state="visible")
        _close_assistant(page)
        page.get_by_role("columnheader", name="APE cm", exact=True).first.wait_for(state="visible")
        page.get_by_role("cell", name="test/ape_cm", exact=True).first.wait_for(state="visible")
        body = page.inner_text("body")
        assert "untrained/" not in body and "test/baseline/" not in body
        assert "baseline:" not in body.split("Metrics (")[0]  # the description's table: this model only
        screenshot(page, "mlflow_surfaces/3_model.png")

        # 3. the runs table in SPADE's view: the run, its predictors as child runs, the rounded figures in view,
        # the deciding one (the planner's APE) the first after the run's name, with its unit
        page.goto(experiment_url)
        for name in ("quickstart", *CHILDREN):
            page.get_by_role("link", name=name, exact=True).first.wait_for(state="visible")
        _close_assistant(page)
        column = page.get_by_role("columnheader", name="planner APE", exact=True).first
        column.wait_for(state="visible")
        assert _in_view(page, column)
        tail = page.get_by_role("columnheader", name="planner over 20 cm", exact=True).first
        assert column.bounding_box()["x"] < tail.bounding_box()["x"]
        dataset = page.get_by_role("columnheader", name="Dataset")  # drawn only when in view: after the figures
        assert not dataset.count() or column.bounding_box()["x"] < dataset.first.bounding_box()["x"]
        page.get_by_role("gridcell").filter(has_text=re.compile(r"^\d+\.\d\d cm$")).first.wait_for(state="visible")
        assert not re.search(r"\d\.\d{5,}", page.inner_text("body"))  # no unrounded figure in view
        picture = screenshot(page, "mlflow_surfaces/4_runs_view.png")
    return picture
