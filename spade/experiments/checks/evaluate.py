"""``spade.evaluate``'s checks: the checkpoint's role, and its geometry against the data it is tested on."""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig

from spade.experiments.checks.checkpoints import _check_geometry, _read_checkpoint
from spade.experiments.checks.data import _check_data, _check_datasets
from spade.experiments.checks.files import check_paths
from spade.experiments.checks.store import _check_logger_store
from spade.experiments.checks.values import _MISSING, _check_bool, _check_int, _get, _unset
from spade.utils.errors import ConfigError


def validate_evaluate_config(cfg: DictConfig) -> None:
    """``spade.evaluate``'s checks: the checkpoint's role, and its geometry against the data it is tested on."""
    check_paths(cfg)
    _check_int(cfg, "seed", 0, 2**32 - 1, fix=", e.g. seed=42")
    # source_seed is logged as the run's cfg/seed only when the test has finished: a bad one failed after a whole
    # evaluation and left a FINISHED run
    _check_int(cfg, "source_seed", 0, 2**32 - 1, none_ok=True,
               fix=": the seed of the training run the checkpoint comes from (null: none)")
    for key in ("open_loop", "closed_loop"):
        _check_bool(cfg, key)
    _check_int(cfg, "mcap_instances", 1, fix=", e.g. mcap_instances=64")
    ckpt = _get(cfg, "ckpt_path")
    fix = "pass a student or expert checkpoint written by python -m spade.train"
    if ckpt in (_MISSING, None, "", "???"):
        raise ConfigError(f"ckpt_path is not set; {fix} (ckpt_path=PATH)")
    path = Path(str(ckpt))
    if not path.exists():
        raise ConfigError(f"ckpt_path={ckpt} does not exist; {fix}")
    if path.is_dir():
        raise ConfigError(f"ckpt_path={ckpt} is a directory, not a checkpoint file; {fix}")
    info = _read_checkpoint("ckpt_path", ckpt, path, fix)
    if info.get("role") not in ("student", "expert"):
        raise ConfigError(f"ckpt_path={ckpt} is not a SPADE student or expert checkpoint (role "
                          f"{info.get('role')!r}); {fix}")
    if _get(cfg, "closed_loop") not in (_MISSING, None, False) and info.get("role") != "student":
        raise ConfigError(f"closed_loop=true drives a planner, and ckpt_path={ckpt} is an {info.get('role')}: pass a "
                          "student checkpoint, or leave closed_loop=false (an expert's test has no closed loop)")
    _check_logger_store(cfg)
    _check_data(cfg)
    # the test set alone is read (the validation split of data.train_dir stands in only without a test_dir)
    scored = ("test",) if not _unset(_get(cfg, "data.test_dir")) else ("train",)
    _check_datasets(cfg, scored)
    _check_geometry("ckpt_path", ckpt, info, cfg, tuple(f"{name}_dir" for name in scored))
