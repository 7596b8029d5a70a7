"""The annotation settings a data config's ``*_generate`` entry asks for: the one function that composes them.

A data config (``conf/data/*.yaml``) names each dataset's folder (``train_dir``, ``test_dir``) and the annotation
settings that make it (``train_generate``, ``test_generate``). :func:`annotation_config` turns such an entry into
the annotation tool's full config; the data module's checks (:mod:`spade.data.checks`), the annotation run that
builds a missing dataset (:func:`spade.annotation.run.generate_dataset`) and the benchmarks all read it from here.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from omegaconf import OmegaConf

from spade.utils.config import compose_config

# (dataset directory, a data config's ``*_generate`` entry) -> None: builds the dataset there. The data configs
# name the annotation tool's (``conf/data/generator/annotate.yaml``: spade.annotation.run.generate_dataset).
Generator = Callable[[Path, Any], None]


def preset_override(name: str) -> str:
    """The Hydra override that selects annotation preset ``name`` (``conf/annotate/preset/<name>.yaml``)."""
    return f"annotate/preset@_global_={name}"


def annotation_config(root: Path, config: Any) -> Any:
    """The annotation tool's config for a data config's ``*_generate`` entry.

    ``config`` holds ``preset`` (a ``conf/annotate/preset`` name), optional ``overrides`` (command-line style
    strings, e.g. ``split=test``) and ``set`` (a dict, or a list of dicts merged in order, e.g. the scale's
    window and instance counts; null values are skipped, keeping the preset's).
    """
    config = OmegaConf.to_container(OmegaConf.create(config), resolve=True) if config is not None else {}
    overrides = [preset_override(config["preset"])] if config.get("preset") else []
    overrides += list(config.get("overrides") or [])
    cfg = compose_config("annotate", overrides)
    layers = config.get("set") or []
    for layer in layers if isinstance(layers, list) else [layers]:
        layer = {k: v for k, v in (layer or {}).items() if v is not None}
        cfg = OmegaConf.merge(cfg, layer)
    return OmegaConf.merge(cfg, {"out_dir": str(root), "overwrite": False})


def dataset_settings(root: Path, generate: Any) -> dict[str, Any]:
    """:func:`annotation_config` as plain, resolved data (what a manifest's ``generator`` records)."""
    return OmegaConf.to_container(annotation_config(root, generate), resolve=True)  # type: ignore[return-value]
