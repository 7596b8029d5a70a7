"""``python -m spade.evaluate ckpt_path=PATH [data=...]``: test a trained student or expert on a test set."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import hydra
import lightning as L
from omegaconf import DictConfig

import spade.paths  # noqa: F401  (registers the ${cwd:} resolver)
from spade.models.modelfile import load_checkpoint, load_lightning
from spade.training.instantiate import instantiate_loggers

log = logging.getLogger(__name__)


def load_module(ckpt_path: str | Path) -> L.LightningModule:
    """Load a SPADE checkpoint as the LightningModule that wrote it (student or expert), safely
    (:func:`spade.models.modelfile.load_lightning`)."""
    path = Path(ckpt_path)
    if not path.is_file():
        raise FileNotFoundError(f"ckpt_path={path} does not exist; pass a checkpoint written by python -m spade.train")
    role = (load_checkpoint(path).get("spade") or {}).get("role")
    if role == "student":
        from spade.training.student_module import StudentModule

        return load_lightning(StudentModule, path)
    if role == "expert":
        from spade.training.expert_module import ExpertModule

        return load_lightning(ExpertModule, path)
    raise ValueError(f"{path} is not a SPADE student or expert checkpoint (role {role!r})")


def evaluate(cfg: DictConfig) -> dict[str, Any]:
    """Test ``cfg.ckpt_path`` on ``cfg.data``'s test set; returns the test metrics."""
    from spade.experiments.validation import validate_evaluate_config

    validate_evaluate_config(cfg)  # role, and the checkpoint's window geometry against the test data's
    L.seed_everything(cfg.seed, workers=True)
    model = load_module(cfg.ckpt_path)
    datamodule = hydra.utils.instantiate(cfg.data)
    loggers = instantiate_loggers(cfg.get("logger"))
    trainer = hydra.utils.instantiate(cfg.trainer, logger=loggers or False, callbacks=[])
    results = trainer.test(model=model, datamodule=datamodule)[0]
    return {k: float(v) for k, v in results.items()}


@hydra.main(version_base="1.3", config_path="../conf", config_name="evaluate")
def main(cfg: DictConfig) -> None:
    from spade.experiments.validation import exit_on_user_error

    metrics = exit_on_user_error(evaluate)(cfg)
    print("\n".join(f"{k}: {v:.4g}" for k, v in sorted(metrics.items())))


if __name__ == "__main__":
    main()
