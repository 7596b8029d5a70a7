"""Composing the project's Hydra configs from code: inside a running Hydra app or from a plain script."""

from __future__ import annotations

from collections.abc import Sequence

from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from omegaconf import DictConfig

from spade.paths import CONF_DIR


def compose_config(config_name: str, overrides: Sequence[str] = (), return_hydra_config: bool = False) -> DictConfig:
    """Compose ``conf/<config_name>.yaml`` with ``overrides`` (Hydra's command-line syntax).

    Inside a running Hydra app (``python -m spade.train``) its config search path is reused; otherwise
    Hydra is initialised on the project's ``conf/`` for the duration of the call.
    """
    if GlobalHydra.instance().is_initialized():
        return compose(config_name=config_name, overrides=list(overrides), return_hydra_config=return_hydra_config)
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        return compose(config_name=config_name, overrides=list(overrides), return_hydra_config=return_hydra_config)
