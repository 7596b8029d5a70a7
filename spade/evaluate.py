"""``python -m spade.evaluate ckpt_path=PATH [data=...]``: test a trained student or expert on a test set."""

from __future__ import annotations

import logging

from spade.utils.threads import prefer_passive_wait

if __name__ == "__main__":  # the command, not an import: before torch is (below), idle OpenMP threads then yield
    prefer_passive_wait()   # their core to a training beside it (spade/utils/threads.py)

import hydra  # noqa: E402
from omegaconf import DictConfig  # noqa: E402

from spade.paths import CONFIG_PATH  # noqa: E402  (the configs, conf/ or the installed copy; registers resolvers)
from spade.utils.errors import run_entry_point, task  # noqa: E402
from spade.experiments.evaluation import evaluate  # noqa: E402
from spade.training.loading import load_module  # noqa: E402

__all__ = ["evaluate", "load_module"]

log = logging.getLogger(__name__)


@hydra.main(version_base="1.3", config_path=CONFIG_PATH, config_name="evaluate")
@task
def main(cfg: DictConfig) -> None:
    from spade.config.refusals import exit_on_user_error

    from spade.utils.signals import install_signal_handlers
    from spade.tracking.summary import evaluation_summary

    install_signal_handlers()  # SIGTERM / SIGINT end the run through an exception: its MLflow run is marked KILLED

    metrics = exit_on_user_error(evaluate)(cfg)
    print("\n".join(f"{k}: {v:.4g}" for k, v in sorted(metrics.items())))
    print(evaluation_summary(cfg, metrics), flush=True)


if __name__ == "__main__":
    run_entry_point(main)
