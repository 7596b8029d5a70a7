"""Where the project's own files are, and the ``${cwd:}`` and ``${spade_package:}`` config resolvers (usable outside a
Hydra app)."""

import os
from pathlib import Path

from omegaconf import OmegaConf

PROJECT_ROOT = Path(__file__).resolve().parents[1]
CONF_DIR = PROJECT_ROOT / "conf"
PACKAGE_DIR = Path(__file__).resolve().parent

OmegaConf.register_new_resolver("cwd", os.getcwd, replace=True)
# ``${spade_package:}``: the installed package's folder, where the files SPADE ships live (conf/paths: weights_dir).
OmegaConf.register_new_resolver("spade_package", lambda: str(PACKAGE_DIR), replace=True)


def _run_uid() -> str:
    """A fresh random id (48 bits from os.urandom, unique across processes and hosts sharing a filesystem)."""
    import uuid

    return uuid.uuid4().hex[:12]


# ``${run_uid:}`` in a run folder name (conf/hydra/default.yaml): cached per config like Hydra's ``${now:}`` (and
# copied to a multirun's jobs with it), so every use within one run gives the same id and no two runs share one.
OmegaConf.register_new_resolver("run_uid", _run_uid, use_cache=True, replace=True)


def _experiment_name(table: str, train_generate: object, train_dir: object) -> str:
    """The MLflow experiment of a training run: its table's (``tags.table``) when the run trains on data SPADE
    generates; ``own_<training folder>`` when it trains on a user's own datasets (``data=own``: no generator), so
    that such runs never join a paper table's experiment (``spade.report`` reads a table from its experiment)."""
    if train_generate is None:
        name = Path(str(train_dir)).name or "data"
        return f"own_{name}"
    return str(table)


# ``${spade_experiment:${tags.table},${oc.select:data.train_generate,null},${oc.select:data.train_dir,null}}``
# (conf/logger/mlflow.yaml).
OmegaConf.register_new_resolver("spade_experiment", _experiment_name, replace=True)
