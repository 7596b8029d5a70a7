"""Issue 48, item 1 in a browser: a real tiny quickstart run (``+experiment=quickstart scale=tiny``, a couple of
batches per stage, the shipped expert), ``mlflow server`` over its store, Debian's chromium at 1600x1000 on the run
page, its logged model page and the runs table in SPADE's view.

Checked, in the store and on the pages: the logged model's metrics are the student's ``test/*`` (and ``model/*``),
no ``untrained/*``, no baseline; the parent run holds no ``untrained/*`` and no ``test/baseline/*`` (those are the
child runs'); the description opens with the figures' table, visible without "Show more"; the runs table lists the
run with its baselines and untrained model as child runs, with the test-metric columns in view. Screenshots go to
``test-artifacts/mlflow_surfaces/`` (the folder is printed); ``SPADE_UPDATE_DOCS_PICTURES=1`` also copies the runs
view to ``docs/assets/mlflow-runs-view.png`` (the picture of docs/reference/tracking.md)."""

from __future__ import annotations

import os
import re
import shutil
from pathlib import Path

import pytest

from browser_support import ARTIFACTS, browser_page, screenshot
from mlflow_server_support import FAST, REPO, printed, served_home  # noqa: F401

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

        # 3. the runs table in SPADE's view: the run, its predictors as child runs, test columns in view
        page.goto(experiment_url)
        for name in ("quickstart", *CHILDREN):
            page.get_by_role("link", name=name, exact=True).first.wait_for(state="visible")
        _close_assistant(page)
        column = page.get_by_role("columnheader", name="test/ape_cm").first
        column.wait_for(state="visible")
        assert _in_view(page, column)
        picture = screenshot(page, "mlflow_surfaces/4_runs_view.png")
    return picture
