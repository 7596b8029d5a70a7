"""``python -m spade.critic ckpt_path=EXPERT [student_ckpt=STUDENT] [margin=NAME] [data.test_dir=DIR]``: the expert as a
critic, measured (the work: :mod:`spade.experiments.critic_run`; the measure: :mod:`spade.training.critic`).

Scores the demonstration against a fixed, versioned set of corruptions (:mod:`spade.metrics.corruptions`) with the
margin formulation of ``margin=`` (the paper's ``cond_dbc`` by default), per timestep band; prints the win rates,
logs them (``critic/win/*``, ``critic/ratio/*``) and a picture to MLflow (experiment ``critic``).
"""

from __future__ import annotations

import hydra
from omegaconf import DictConfig

from spade.paths import CONFIG_PATH  # the configs (conf/ or the installed copy); registers the resolvers
from spade.utils.errors import run_entry_point, task


@hydra.main(version_base="1.3", config_path=CONFIG_PATH, config_name="critic")
@task
def main(cfg: DictConfig) -> None:
    from spade.config.critic_checks import validate_critic_config
    from spade.config.refusals import exit_on_user_error
    from spade.experiments.critic_run import critic, format_report

    exit_on_user_error(validate_critic_config)(cfg)  # every bad input: one `error:` line, exit 2, before any work
    metrics = exit_on_user_error(critic)(cfg)
    print(format_report(metrics))


if __name__ == "__main__":
    run_entry_point(main)
