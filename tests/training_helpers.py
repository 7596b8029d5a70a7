"""Shared set-up for the training tests: tiny datasets under a temporary SPADE_HOME, tiny checkpoints."""

from __future__ import annotations

import os
from pathlib import Path

from omegaconf import DictConfig, open_dict

from spade.utils.config import compose_config


def compose_row(experiment: str, home: Path, *overrides: str, hydra_config: bool = False) -> DictConfig:
    """Compose ``+experiment=...`` at tiny scale with every path under ``home`` and no MLflow logger."""
    os.environ["SPADE_HOME"] = str(home)
    cfg = compose_config(
        "train",
        [f"+experiment={experiment}", "scale=tiny", f"paths.output_dir={home}/out/{experiment}", *overrides],
        return_hydra_config=hydra_config,
    )
    with open_dict(cfg):
        cfg.paths.mlflow_tracking_uri = f"sqlite:///{home}/mlflow.db"
    return cfg
