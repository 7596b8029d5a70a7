"""Building callbacks and loggers from Hydra config groups (lightning-hydra-template style)."""

from __future__ import annotations

import functools
import logging
from pathlib import Path

import hydra
from lightning import Callback
from lightning.pytorch.loggers import Logger
from omegaconf import DictConfig

from spade.models.modelfile import read_info

log = logging.getLogger(__name__)


def instantiate_callbacks(cfg: DictConfig | None, run_cfg: DictConfig | None = None) -> list[Callback]:
    """Every ``_target_`` entry of the callbacks group, in order. An entry marked ``_partial_: true`` is a
    callback that needs the run's whole config: it is built with ``cfg=run_cfg`` (the run's MLflow record,
    ``spade.tracking.callback.RunRecord``)."""
    callbacks: list[Callback] = []
    for name, conf in (cfg or {}).items():
        if isinstance(conf, DictConfig) and "_target_" in conf:
            log.info("Instantiating callback %s <%s>", name, conf._target_)
            built = hydra.utils.instantiate(conf)
            callbacks.append(built(cfg=run_cfg) if isinstance(built, functools.partial) else built)
    return callbacks


def instantiate_loggers(cfg: DictConfig | None, run_id: str | None = None) -> list[Logger]:
    """Every ``_target_`` entry of the logger group; an MLflow logger resumes ``run_id`` when given."""
    loggers: list[Logger] = []
    for name, conf in (cfg or {}).items():
        if isinstance(conf, DictConfig) and "_target_" in conf:
            extra = {}
            if conf._target_.endswith("MLFlowLogger"):
                if run_id:
                    extra["run_id"] = run_id
                if conf.get("tags"):
                    # MLflow tags are strings; a file store stringifies numbers itself, a REST store
                    # (`mlflow server`) refuses them (e.g. a sweep's `lambda: ${model.margin.lambda_dm}`).
                    extra["tags"] = {str(k): str(v) for k, v in conf.tags.items() if v is not None}
            log.info("Instantiating logger %s <%s>", name, conf._target_)
            loggers.append(hydra.utils.instantiate(conf, **extra))
    return loggers


def run_id_from_checkpoint(ckpt_path: str | Path | None) -> str | None:
    """The MLflow run id a checkpoint was written under (so that a resumed run continues that run)."""
    if not ckpt_path:
        return None
    path = Path(ckpt_path)
    if not path.is_file():
        raise FileNotFoundError(
            f"ckpt_path={path} does not exist; pass the path of a checkpoint written by an earlier run "
            "(they live under the run's output directory, checkpoints/last.ckpt)"
        )
    return read_info(path, checkpoint=True, required=False).get("mlflow_run_id")
