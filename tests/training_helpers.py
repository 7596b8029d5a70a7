"""Shared set-up for the training tests: tiny datasets under a temporary SPADE_HOME, tiny checkpoints."""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig, open_dict

from spade.utils.config import compose_config


def compose_row(experiment: str, home: Path, *overrides: str, hydra_config: bool = False) -> DictConfig:
    """Compose ``+experiment=...`` at tiny scale with every path under ``home`` (``paths.root_dir``: what
    SPADE_HOME would set, without touching the environment)."""
    cfg = compose_config(
        "train",
        [f"+experiment={experiment}", "scale=tiny", f"paths.root_dir={home}", f"paths.output_dir={home}/out/{experiment}",
         *overrides],
        return_hydra_config=hydra_config,
    )
    with open_dict(cfg):
        cfg.paths.mlflow_tracking_uri = f"sqlite:///{home}/mlflow.db"
    return cfg
