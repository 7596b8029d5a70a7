"""Issue 48, item 1 (fast, in-process): what a run shows in MLflow. The references (baselines, untrained model) are
only child runs, every test figure sits at one step, the margin shares the validation's x axis, each predictor kind
has its colour, the description opens with the figures' table (units, rounded) and states the test set's
composition and the measured wall time; readers fold the child runs back in. Item 5: one palette."""

from __future__ import annotations

from pathlib import Path

import pytest


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
