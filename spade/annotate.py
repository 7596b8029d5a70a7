"""Demonstration annotation tool (Hydra CLI): ``python -m spade.annotate [preset=...] [key=value ...]``.

Sources, in order of precedence: ``sketches=`` (an operator's sketch file), ``rosbag.paths=`` (rosbag2
recordings), ``skipp.root=`` (SKIPP's published layout), else shape templates on ``maps=``. See
``conf/annotate.yaml`` for every setting.

Examples::

    python -m spade.annotate preset=lshape                          # 10,000 L instances on 10 procedural maps
    python -m spade.annotate preset=ushape maps=../shared/maps      # on every real map of a folder
    python -m spade.annotate shape=U maps=[warehouse:1,hall:4] num_instances=500 seed=3 out_dir=data/u500
    python -m spade.annotate sketches=my_sketches.yaml out_dir=data/mine
"""

from __future__ import annotations

import sys

import hydra
from omegaconf import DictConfig, OmegaConf

from spade.annotation.run import alias_preset
from spade.annotation.run import annotate
from spade.paths import CONFIG_PATH  # the configs (conf/ or the installed copy); registers the resolvers
from spade.utils.errors import run_entry_point, task
from spade.config.annotate_checks import validate_annotate_config

__all__ = ["annotate", "main"]


def _checked_annotate(cfg: DictConfig) -> dict:
    """The config and inputs checked first (one ``error:`` line, exit 2), then the run."""
    validate_annotate_config(cfg)
    return annotate(cfg)


@hydra.main(config_path=CONFIG_PATH, config_name="annotate", version_base="1.3")
@task
def main(cfg: DictConfig) -> None:
    from spade.config.refusals import exit_on_user_error

    summary = exit_on_user_error(_checked_annotate)(cfg)
    print(OmegaConf.to_yaml(OmegaConf.create(summary)))


if __name__ == "__main__":
    sys.argv = [sys.argv[0], *alias_preset(sys.argv[1:])]
    run_entry_point(main)
