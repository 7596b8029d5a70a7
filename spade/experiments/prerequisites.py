"""Prerequisites of a run: the margin's expert or a pretrained student, found in the registry or trained first.

An experiment names what it needs in its ``requires`` section::

    requires:
      expert:
        experiment: cond_expert_L          # the experiment that trains it
        target: model.margin.expert_ckpt   # the config key its checkpoint fills
        version: champion                  # which registered version: an alias, a number, or latest

When ``target`` is already set (an explicit checkpoint path) nothing happens. Otherwise the requirement's
config is composed with the parent's scale, recipe, paths, trainer and logger overrides, its registry name is
derived (role, shape, size and data fingerprint), and the version ``version`` names is used: by default the
``champion`` alias, which the first registered version receives and later ones do not take
(:mod:`spade.tracking.registry`), so a row re-run after another expert was trained uses the same expert. The
version used is written into the run's config as ``requires.<key>.resolved`` (name, version, run id: logged with
the run's parameters). If none is registered, ``prerequisites=train`` (default) has it trained first, and
``prerequisites=error`` stops with the exact command.

This module never trains anything itself (it imports neither :mod:`spade.train` nor :mod:`spade.experiments.run`):
:func:`pending_prerequisites` fills what is registered and returns what must be trained;
:func:`spade.experiments.run.train` trains each one, calls :func:`complete_prerequisite`, and then re-seeds, so a
run's numbers do not depend on whether its prerequisites were trained in the same process.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf, open_dict

from spade.tracking.registry import CHAMPION_ALIAS as CHAMPION, RegisteredCheckpoint, fetch_registered, registry_name
from spade.utils.config import compose_config
from spade.utils.errors import UserError

log = logging.getLogger(__name__)

# Parent overrides that a prerequisite inherits (so it runs at the same scale, into the same store).
INHERITED = ("scale", "recipe", "paths", "trainer", "logger", "seed", "data.num_workers", "prerequisites")


class PrerequisiteMissing(UserError, RuntimeError):
    """A required model is not registered and ``prerequisites=error``."""


@dataclass(frozen=True)
class Prerequisite:
    """A required model that is not registered yet: what to train, and where its checkpoint goes."""

    key: str  # the entry of ``requires``
    experiment: str  # the experiment that trains it
    target: str  # the config key its checkpoint fills
    name: str  # its registered model name
    config: DictConfig  # the composed config that trains it
    command: str  # the command that trains it on its own


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


def fill_prerequisite(cfg: DictConfig, key: str, target: str, found: RegisteredCheckpoint) -> None:
    """Fill ``target`` with the downloaded checkpoint and record which registered version it is."""
    with open_dict(cfg):
        OmegaConf.update(cfg, target, str(found.path), merge=False)
        cfg.requires[key].resolved = {"name": found.name, "version": found.version, "run_id": found.run_id}
    log.info("Prerequisite %s: %s, %s", key, found.describe(), found.path)


def pending_prerequisites(cfg: DictConfig, depth: int = 0) -> list[Prerequisite]:
    """Fill every unset ``requires.*.target`` of ``cfg`` whose model is registered; return the others.

    With ``prerequisites=error`` a missing one raises :class:`PrerequisiteMissing` with the command to run.
    """
    requires = cfg.get("requires") or {}
    pending = []
    for key, req in requires.items():
        target = req.target
        if OmegaConf.select(cfg, target) not in (None, "", "???"):
            continue
        if depth > 4:
            raise RecursionError(f"prerequisite chain too deep at {key} ({req.experiment})")
        overrides = [o for o in _parent_overrides() if not o.lstrip("+~").startswith(("scale=", "recipe="))]
        overrides += [f"scale={cfg.scale.name}", f"recipe={cfg.recipe.name}"]
        out_dir = f"{cfg.paths.output_dir}/prerequisites/{req.experiment}"
        sub = compose_experiment(req.experiment, [*overrides, f"paths.output_dir={out_dir}"])
        name = registry_name(sub)
        if name is None:
            raise ValueError(f"experiment {req.experiment} registers no model (registry.prefix unset)")
        tracking_uri = cfg.paths.mlflow_tracking_uri
        found = fetch_registered(tracking_uri, name, cfg.paths.registry_cache_dir, req.get("version") or CHAMPION)
        if found is not None:
            fill_prerequisite(cfg, str(key), target, found)
            continue
        command = " ".join(["python -m spade.train", f"+experiment={req.experiment}", *overrides])
        if cfg.get("prerequisites", "train") == "error":
            raise PrerequisiteMissing(
                f"{key}: registered model {name} not found in {tracking_uri}. Train it first with:  {command}"
            )
        pending.append(Prerequisite(str(key), str(req.experiment), str(target), name, sub, command))
    return pending


def complete_prerequisite(cfg: DictConfig, prerequisite: Prerequisite) -> Path:
    """After ``prerequisite`` was trained: fetch its registered checkpoint and fill its target key of ``cfg``."""
    version = cfg.requires[prerequisite.key].get("version") or CHAMPION
    found = fetch_registered(cfg.paths.mlflow_tracking_uri, prerequisite.name, cfg.paths.registry_cache_dir,
                             version)
    if found is None:
        raise PrerequisiteMissing(
            f"{prerequisite.key}: training {prerequisite.experiment} registered no model {prerequisite.name}"
        )
    fill_prerequisite(cfg, prerequisite.key, prerequisite.target, found)
    return found.path
