"""``python -m spade.evaluate ckpt_path=PATH [data=...]``: test a trained student or expert on a test set."""

from __future__ import annotations

import logging

import hydra
from omegaconf import DictConfig

from spade.paths import CONFIG_PATH  # the configs (conf/ or the installed copy); registers the resolvers
from spade.utils.errors import run_entry_point, task
from spade.experiments.evaluation import evaluate
from spade.training.loading import load_module

__all__ = ["evaluate", "load_module"]

log = logging.getLogger(__name__)


@hydra.main(version_base="1.3", config_path=CONFIG_PATH, config_name="evaluate")
@task
def main(cfg: DictConfig) -> None:
    from spade.experiments.checks import exit_on_user_error

    metrics = exit_on_user_error(evaluate)(cfg)
    print("\n".join(f"{k}: {v:.4g}" for k, v in sorted(metrics.items())))


if __name__ == "__main__":
    run_entry_point(main)
