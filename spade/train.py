"""``python -m spade.train [+experiment=NAME] [key=value ...]``: train, validate and test one model.

A thin Hydra entry point in the style of lightning-hydra-template: the config (``conf/train.yaml``) composes
data, model, margin, trainer, logger, callbacks and paths; :func:`spade.experiments.run.train` resolves the run's
prerequisites (the margin's expert, a pretrained student) and trains; this entry point prints the closing summary
from what it returns (:func:`spade.tracking.summary.run_summary`) and hands ``optimized_metric``'s value to Hydra so
that sweepers can optimise it. A user
error (a bad config, a missing dataset or prerequisite) ends the process with one line and exit status 2.
"""

from __future__ import annotations

import logging

from spade.utils.threads import configure_threads, prefer_passive_wait

if __name__ == "__main__":  # the command, not an import: before torch is (below), idle OpenMP threads then yield
    prefer_passive_wait()   # their core to other runs (spade/utils/threads.py)

import hydra  # noqa: E402
from omegaconf import DictConfig, OmegaConf  # noqa: E402

from spade.paths import CONFIG_PATH  # noqa: E402  (the configs, conf/ or the installed copy; registers resolvers)
from spade.utils.errors import run_entry_point, task  # noqa: E402
from spade.config.refusals import exit_on_user_error  # noqa: E402

log = logging.getLogger(__name__)


@hydra.main(version_base="1.3", config_path=CONFIG_PATH, config_name="train")
@task
def main(cfg: DictConfig) -> float | None:
    # here, not at the top: the training stack loads once the config has composed (``--help`` and Hydra's own
    # errors need none of it), and its preflight (spade.config.preflight) is the only command's checks it loads
    from spade.utils.signals import install_signal_handlers
    from spade.experiments.run import sweep_result, train
    from spade.tracking.summary import run_summary

    log.debug("Config:\n%s", OmegaConf.to_yaml(cfg))
    install_signal_handlers()
    renamed = cfg.get("deprecated_experiment")
    if renamed:  # an experiment's old name, accepted for one release
        log.warning("+experiment=%s is deprecated: it is now +experiment=%s (docs/reference/glossary.md)",
                    renamed.old, renamed.new)
    threads = exit_on_user_error(configure_threads)(cfg.get("threads"))
    log.info("torch intra-op threads: %d (threads=%s)", threads, cfg.get("threads"))
    metrics, objects = exit_on_user_error(train)(cfg)
    print(run_summary(cfg, metrics, getattr(objects["model"], "margin_history", None), objects["checkpoint"] or None,
                      objects["run"]), flush=True)
    return sweep_result(cfg, metrics)


if __name__ == "__main__":
    run_entry_point(main)
