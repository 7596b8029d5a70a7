"""``spade.report``'s table published in MLflow: its experiment tagged, its chart in its rows' runs, the UI links."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from spade.tracking.client import mlflow_client
from spade.tracking.experiment_tags import ensure_experiment_tags
from spade.tracking.links import SWITCH_HINT, experiment_url, run_url, ui_base_url, ui_command


def publish_report(table: Any, results: dict[str, Any], tracking_uri: str, files: dict[str, Path],
                   log_to_runs: bool = True) -> list[str]:
    """After ``spade.report`` wrote a table: tag its experiment (:func:`ensure_experiment_tags`), log the chart and
    the markdown into each shown row's run (``report/<table>.png``, ``report/<table>.md``: the run page's
    Artifacts tab) and return the lines that open the table in the MLflow UI."""
    client = mlflow_client(tracking_uri)
    experiment = client.get_experiment_by_name(table.experiment)
    if experiment is None:
        return []
    ensure_experiment_tags(client, experiment)
    logged = 0
    if log_to_runs and files.get("png"):
        for result in results.values():
            # Only SPADE training runs (they all hold config/train.yaml), never runs made by other tools.
            if result.run_id and client.list_artifacts(result.run_id, "config"):
                for key in ("png", "markdown"):
                    if files.get(key):
                        client.log_artifact(result.run_id, str(files[key]), artifact_path="report")
                logged += 1
    base = ui_base_url(tracking_uri)
    command = ui_command(tracking_uri)
    lines = ["MLflow UI" + (f" (`{command}`)" if command else "") + ":",
             f"- runs of `{table.experiment}`: {experiment_url(base, experiment.experiment_id)}"]
    lines += [f"- {row}: {run_url(base, experiment.experiment_id, r.run_id)}" for row, r in results.items() if r.run_id]
    if logged:
        lines.append(f"- the chart is in each of those {logged} runs as `report/{table.key}.png` (Artifacts tab)")
    lines.append(f"- {SWITCH_HINT.strip()}")
    return lines
