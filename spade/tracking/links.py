"""Links into the MLflow UI: its address, the URLs of runs, runs tables and artifacts, the ``mlflow ui`` command.

:func:`ui_lines` gives the command that serves a local store and the URLs of a run and its experiment's runs
table, printed at the end of training and by ``spade.report``. Every URL carries ``?workflowType=machine_learning``
(MLflow 3 UIs otherwise open on the GenAI view: the URL's ``workflowType``, else the sidebar's switch as the browser
stored it, decides; the experiment's tags do not); the runs table opens on SPADE's view stored in the experiment
(:data:`VIEW_KEY`; the view itself: :func:`spade.tracking.experiment_tags.runs_view_state`).
"""

from __future__ import annotations

import os
from urllib.parse import quote, urlsplit

WORKFLOW_QUERY = "workflowType=machine_learning"  # MLflow 3 UIs: open on runs, not on GenAI traces
# A runs-table view stored in the experiment (the MLflow UI's "shared view": tag mlflow.sharedViewState.<key>,
# opened by ?viewStateShareKey=<key>): the rounded test figures, the deciding one first, then the Dataset column,
# runs sorted by name (each row's run followed by its baselines and untrained model).
VIEW_KEY = "spade"
DEFAULT_UI = "http://127.0.0.1:5000"  # where `mlflow ui` listens unless told otherwise
UI_URL_ENV = "SPADE_MLFLOW_UI_URL"  # the UI's address when it is not `mlflow ui`'s default (another port, a proxy)


def is_server_uri(tracking_uri: str) -> bool:
    return str(tracking_uri).startswith(("http://", "https://"))


def ui_base_url(tracking_uri: str, ui_url: str | None = None) -> str:
    """The UI's address: ``ui_url``, else ``$SPADE_MLFLOW_UI_URL``, else the tracking server itself for
    ``http(s)://`` URIs, else where ``mlflow ui`` listens by default."""
    ui_url = ui_url or os.environ.get(UI_URL_ENV)
    if ui_url:
        if not str(ui_url).startswith(("http://", "https://")):
            raise ValueError(f"{UI_URL_ENV}={ui_url!r}: the MLflow UI's address must start with http:// or https://")
        return str(ui_url).rstrip("/")
    return str(tracking_uri).rstrip("/") if is_server_uri(tracking_uri) else DEFAULT_UI


def experiment_url(base: str, experiment_id: str, view: bool = True) -> str:
    """The experiment's runs table (MLflow's hash routes; the query keeps 3.x UIs off the GenAI view), with
    SPADE's view of it (:func:`~spade.tracking.experiment_tags.runs_view_state`: the rounded
    test figures shown, the deciding one first) unless ``view=False``."""
    query = f"viewStateShareKey={VIEW_KEY}&{WORKFLOW_QUERY}" if view else WORKFLOW_QUERY
    return f"{base.rstrip('/')}/#/experiments/{experiment_id}/runs?{query}"


def run_url(base: str, experiment_id: str, run_id: str) -> str:
    return f"{base.rstrip('/')}/#/experiments/{experiment_id}/runs/{run_id}?{WORKFLOW_QUERY}"


def artifact_url(base: str, experiment_id: str, run_id: str, path: str) -> str:
    """A run's Artifacts tab with ``path`` selected (PNG files are shown as pictures); ``base=''`` gives a link
    relative to the UI's page, for descriptions."""
    prefix = f"{base.rstrip('/')}/" if base else ""
    return f"{prefix}#/experiments/{experiment_id}/runs/{run_id}/artifacts/{quote(path)}?{WORKFLOW_QUERY}"


def relative_run_link(experiment_id: str, run_id: str) -> str:
    """A link that works inside the MLflow UI whatever its address (its routes live in the URL's fragment)."""
    return f"#/experiments/{experiment_id}/runs/{run_id}?{WORKFLOW_QUERY}"


def ui_command(tracking_uri: str, ui_url: str | None = None) -> str | None:
    """The command that serves the UI on a local store (None for a tracking server, which serves its own UI),
    with ``--port`` when the UI's address (:func:`ui_base_url`) is a local one on another port than 5000."""
    if is_server_uri(tracking_uri):
        return None
    command = f"mlflow ui --backend-store-uri {tracking_uri}"
    address = urlsplit(ui_base_url(tracking_uri, ui_url))
    if address.hostname in ("127.0.0.1", "localhost") and address.port not in (None, 5000):
        command += f" --port {address.port}"
    return command


SWITCH_HINT = ("  in a new browser: set the sidebar's switch to \"Model training\" once (else MLflow 3 opens the "
               "GenAI overview)")


def ui_lines(tracking_uri: str, experiment_id: str | None = None, run_id: str | None = None,
             ui_url: str | None = None) -> list[str]:
    """How to open the UI: the ``mlflow ui`` command (local stores), the run's and experiment's URLs and, last, the
    one click that makes a browser open experiments on their runs (:data:`SWITCH_HINT`: MLflow 3.17 chooses an
    experiment's first page by the sidebar's GenAI / Model training switch, not by the experiment's tags; see
    :mod:`~spade.tracking.experiment_tags`)."""
    base = ui_base_url(tracking_uri, ui_url)
    command = ui_command(tracking_uri, ui_url)
    lines = [f"open the MLflow UI on it with:  {command}" if command else f"open the MLflow UI on it at:  {base}"]
    if experiment_id is not None:
        if run_id is not None:
            # the label short: the URL (about 105 characters) and it fit the console's 120 columns
            lines.append(f"  this run: {run_url(base, experiment_id, run_id)}")
        lines.append(f"  experiment's runs: {experiment_url(base, experiment_id)}")
    lines.append(SWITCH_HINT)
    return lines
