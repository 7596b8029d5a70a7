"""Prerequisites of a run: a guidance expert or a pretrained student, found in the registry or trained first.

An experiment names what it needs in its ``requires`` section::

    requires:
      expert:
        experiment: expert_cond_L          # the experiment that trains it
        target: model.guidance.expert_ckpt # the config key its checkpoint fills

When ``target`` is already set (an explicit checkpoint path) nothing happens. Otherwise the requirement's
config is composed with the parent's scale, paths, trainer and logger overrides, its registry name is derived
(role, shape, size and data fingerprint), and the newest registered version is used. If none is registered,
``prerequisites=train`` (default) trains it first, and ``prerequisites=error`` stops with the exact command.
"""

from __future__ import annotations

import logging

from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf, open_dict

from spade.experiments.registry import fetch_checkpoint, registry_name
from spade.experiments.config import compose_config

log = logging.getLogger(__name__)

# Parent overrides that a prerequisite inherits (so it runs at the same scale, into the same store).
INHERITED = ("scale", "paths", "trainer", "logger", "seed", "data.num_workers", "prerequisites")


class PrerequisiteMissing(RuntimeError):
    """A required model is not registered and ``prerequisites=error``."""


def _parent_overrides() -> list[str]:
    if not HydraConfig.initialized():
        return []
    out = []
    for item in HydraConfig.get().overrides.task:
        key = item.split("=", 1)[0].lstrip("+~")
        if key.startswith(INHERITED):
            out.append(item)
    return out


def compose_experiment(name: str, overrides: list[str]) -> DictConfig:
    """Compose ``train`` with ``+experiment=name`` and ``overrides`` (inside or outside a Hydra app)."""
    return compose_config("train", [f"+experiment={name}", *overrides])


def resolve_prerequisites(cfg: DictConfig, depth: int = 0) -> None:
    """Fill every unset ``requires.*.target`` of ``cfg`` with a registered (or freshly trained) checkpoint."""
    requires = cfg.get("requires") or {}
    for key, req in requires.items():
        target = req.target
        if OmegaConf.select(cfg, target) not in (None, "", "???"):
            continue
        if depth > 4:
            raise RecursionError(f"prerequisite chain too deep at {key} ({req.experiment})")
        overrides = [o for o in _parent_overrides() if not o.lstrip("+~").startswith("scale=")]
        overrides.append(f"scale={cfg.scale.name}")
        out_dir = f"{cfg.paths.output_dir}/prerequisites/{req.experiment}"
        sub = compose_experiment(req.experiment, [*overrides, f"paths.output_dir={out_dir}"])
        name = registry_name(sub)
        if name is None:
            raise ValueError(f"experiment {req.experiment} registers no model (registry.prefix unset)")
        tracking_uri = cfg.paths.mlflow_tracking_uri
        ckpt = fetch_checkpoint(tracking_uri, name, cfg.paths.registry_cache_dir)
        if ckpt is None:
            command = " ".join(["python -m spade.train", f"+experiment={req.experiment}", *overrides])
            if cfg.get("prerequisites", "train") == "error":
                raise PrerequisiteMissing(
                    f"{key}: registered model {name} not found in {tracking_uri}. Train it first with:\n  {command}"
                )
            log.info("Prerequisite %s (%s) is not registered: training it first (%s)", key, name, command)
            from spade.train import train

            train(sub)
            ckpt = fetch_checkpoint(tracking_uri, name, cfg.paths.registry_cache_dir)
            if ckpt is None:
                raise PrerequisiteMissing(f"{key}: training {req.experiment} registered no model {name}")
        log.info("Prerequisite %s: %s", key, ckpt)
        with open_dict(cfg):
            OmegaConf.update(cfg, target, str(ckpt), merge=False)
