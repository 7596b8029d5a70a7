"""Small helpers for sending pictures and one-off figures to whichever Lightning logger a run uses."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
from lightning.pytorch.loggers import Logger, MLFlowLogger
from PIL import Image

log = logging.getLogger(__name__)


def log_image(logger: Logger | None, image: np.ndarray, artifact_file: str, fallback_dir: str | Path | None) -> None:
    """Log an RGB uint8 image as an MLflow artifact, or save it under ``fallback_dir`` for other loggers."""
    if isinstance(logger, MLFlowLogger):
        logger.experiment.log_image(logger.run_id, image, artifact_file=artifact_file)
        return
    if fallback_dir is None:
        return
    path = Path(fallback_dir) / artifact_file
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(image).save(path)


def log_table_csv(logger: Logger | None, rows: list[dict], artifact_file: str, fallback_dir: str | Path | None) -> None:
    """Log ``rows`` (dicts with the same keys) as a CSV artifact of the MLflow run, or save it under ``fallback_dir``
    for other loggers."""
    import csv
    import io

    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(rows[0]))
    writer.writeheader()
    writer.writerows(rows)
    if isinstance(logger, MLFlowLogger):
        logger.experiment.log_text(logger.run_id, buffer.getvalue(), artifact_file=artifact_file)
        return
    if fallback_dir is None:
        return
    path = Path(fallback_dir) / artifact_file
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(buffer.getvalue())
