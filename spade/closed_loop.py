"""``python -m spade.closed_loop``: drive trained rows in closed loop, every seed, on each scenario set and
condition (conf/closed_loop.yaml); ``python -m spade.report table=closed_loop`` writes the page. The work is done by
:mod:`spade.experiments.closed_loop_table`; this is its entry point."""

from __future__ import annotations

import hydra
from omegaconf import DictConfig

from spade.paths import CONFIG_PATH  # noqa: F401  (the configs, conf/ or the installed copy; registers resolvers)
from spade.utils.errors import run_entry_point, task


@hydra.main(version_base="1.3", config_path=CONFIG_PATH, config_name="closed_loop")
@task
def main(cfg: DictConfig) -> None:
    from spade.config.drive_checks import validate_closed_loop_config
    from spade.config.refusals import exit_on_user_error
    from spade.experiments.closed_loop_table import launch

    exit_on_user_error(validate_closed_loop_config)(cfg)  # every source, scenario set and condition, before any drive
    ran = exit_on_user_error(launch)(cfg)
    print(f"closed loop: {len(ran)} drives run; report: python -m spade.report table=closed_loop "
          f"scale={cfg.scale.name} output_dir=docs/results", flush=True)


if __name__ == "__main__":
    run_entry_point(main)
