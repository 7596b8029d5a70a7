"""Where the project's own files are, and the ``${cwd:}`` and ``${spade_package:}`` config resolvers (usable outside a
Hydra app)."""

import os
from pathlib import Path

from omegaconf import OmegaConf

PROJECT_ROOT = Path(__file__).resolve().parents[1]
PACKAGE_DIR = Path(__file__).resolve().parent
# The Hydra configs: the repository's conf/ (a checkout, an editable install, PYTHONPATH=.), else the copy an
# installed wheel carries as spade/conf (pyproject's package data), so that every entry point runs from any folder.
CONF_DIR = PROJECT_ROOT / "conf" if (PROJECT_ROOT / "conf" / "train.yaml").is_file() else PACKAGE_DIR / "conf"
CONFIG_PATH = str(CONF_DIR)  # hydra.main's config_path (an absolute folder)

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


def _own_experiment(train_dir: object) -> str:
    """``own_<training folder>``: the MLflow experiment of runs on a user's own datasets (``conf/data/own.yaml``),
    so that such runs never join a paper table's experiment (``spade.report`` reads a table from its experiment)."""
    return f"own_{Path(str(train_dir)).name or 'data'}"


# ``${spade_own_experiment:${.train_dir}}`` (conf/data/own.yaml).
OmegaConf.register_new_resolver("spade_own_experiment", _own_experiment, replace=True)
