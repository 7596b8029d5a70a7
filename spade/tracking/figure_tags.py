"""A run's test figures rounded for the MLflow runs view: one run tag per figure, beside the full-precision metrics.

MLflow's runs table prints a metric as logged (``4.875823020935059``) and names its column by the whole key, cut to
the column's width (``test/planner/ape_cm`` and ``test/planner/ape_over_floor`` both read ``test/planner/ape``).
SPADE keeps the metrics at full precision and also tags each tested run (and each of its predictors' child runs)
with the figures of :data:`~spade.metrics.catalog.RUNS_VIEW`, formatted as the catalog formats them, with their
units: tag ``planner APE`` = ``4.88 cm``, ``planner over 20 cm`` = ``3.2%``. SPADE's runs view
(:func:`~spade.tracking.experiment_tags.runs_view_state`) shows those tags as its first columns, the deciding
figure first; the metrics stay one click away (the Columns menu, the run page) and sort numerically.
"""

from __future__ import annotations

import math
import re
from typing import Any, Mapping

from mlflow.entities import RunTag

from spade.metrics import catalog

__all__ = ["FIGURES", "figure_tags", "log_figure_tags", "tag_key"]

FIGURES = catalog.RUNS_VIEW
_UNITS_SHOWN = ("cm", "ms", "s", "px")  # units a formatted value does not carry itself (a share carries its %)
_VALID_KEY = re.compile(r"[/\w.\- ]+")  # what MLflow accepts as a tag key on every platform


def tag_key(name: str) -> str:
    """The run tag a figure is shown under: its catalog label without the bracketed unit and in the characters
    MLflow accepts (``planner/ape_cm`` -> ``planner APE``, ``planner/over_20cm_rate`` -> ``planner over 20 cm``)."""
    key = re.sub(r"\s*\([^)]*\)", "", catalog.label(name)).replace(">", "over ").strip()
    if not _VALID_KEY.fullmatch(key):  # pragma: no cover - a catalog label MLflow cannot take is a bug here
        raise ValueError(f"{name}: tag key {key!r} is not a valid MLflow tag key; change its label in the catalog")
    return key


def _shown(name: str, value: float) -> str:
    unit = catalog.figure(name).unit
    text = catalog.fmt(name, value)
    return f"{text} {unit}" if unit in _UNITS_SHOWN else text


def figure_tags(metrics: Mapping[str, float], stage: str = "test") -> dict[str, str]:
    """``{tag key: rounded value with its unit}`` for each figure of :data:`FIGURES` that ``metrics`` holds under
    ``stage`` (``test/planner/ape_cm``; ``model/params`` as it is); a missing or NaN figure gets no tag."""
    out = {}
    for name in FIGURES:
        value = metrics.get(catalog.mlflow_key(name, stage))
        if value is None or (isinstance(value, float) and math.isnan(value)):
            continue
        out[tag_key(name)] = _shown(name, float(value))
    return out


def log_figure_tags(client: Any, run_id: str, metrics: Mapping[str, float], stage: str = "test") -> dict[str, str]:
    """Tag run ``run_id`` with :func:`figure_tags` of ``metrics`` (one batch); returns the tags."""
    tags = figure_tags(metrics, stage)
    if tags:
        client.log_batch(run_id, tags=[RunTag(k, v) for k, v in tags.items()])
    return tags
