"""Checks of a checkpoint that a config names.

The file exists and is SPADE's (its ``spade`` entry, read without running code), of the role its key takes (a
student given as ``model.margin.expert_ckpt`` is refused); a file SPADE ships hashes to its pin; and the window
geometry it was trained on is the data's.
"""

from __future__ import annotations

import json
import math
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from omegaconf import DictConfig

from spade.config.dataset_checks import DataSources
from spade.config.options import read_options
from spade.data.checks import data_geometry
from spade.utils.errors import ConfigError
from spade.training.module_options import ExpertOptions


def checkpoint_info(path: str | Path) -> dict[str, Any]:
    """The ``spade`` entry of a checkpoint (role, network config, window geometry, MLflow run id).

    Reads only that entry's plain values, through :func:`spade.models.modelfile.read_info` (``weights_only=True``,
    memory-mapped, so no tensor data is read and no code is run; a checkpoint that would run code is refused);
    ``{}`` for a checkpoint without the entry.
    """
    from spade.models.modelfile import read_info  # heavy: spade.models imports diffusers

    return read_info(path, checkpoint=True, required=False)


def expert_timesteps(path: str | Path) -> int:
    """The number of training timesteps T of the expert checkpoint at ``path`` (its hyper-parameter
    ``num_train_timesteps``; the expert's default, 1000, when it records none), read as :func:`checkpoint_info`
    reads the entry: memory-mapped, no code run."""
    from spade.models.modelfile import load_checkpoint  # heavy: spade.models imports diffusers
    p = Path(path)
    hyper = load_checkpoint(p, mmap=zipfile.is_zipfile(p)).get("hyper_parameters")
    value = hyper.get("num_train_timesteps") if isinstance(hyper, Mapping) else None
    if isinstance(value, int) and not isinstance(value, bool) and value >= 2:
        return value
    return int(ExpertOptions.num_train_timesteps)


def check_checkpoint(key: str, value: Any, role: str, fix: str) -> dict[str, Any] | None:
    """The ``spade`` entry of the checkpoint at config ``key``, checked to exist and to hold ``role``."""
    if value in (None, "", "???"):
        return None
    path = Path(str(value))
    if path.is_dir():
        raise ConfigError(f"{key}={value} is a directory, not a checkpoint file; {fix}")
    if not path.is_file():
        raise ConfigError(f"{key}={value} does not exist; {fix}")
    check_shipped(key, path)
    info = read_checkpoint(key, value, path, fix)
    have = info.get("role")
    if have != role:
        what = f"{_a(have)} {have} checkpoint" if have else "not a SPADE checkpoint (no 'spade' entry)"
        raise ConfigError(f"{key}={value} is {what}, this key takes {_a(role)} {role} checkpoint; {fix}")
    return info


def read_checkpoint(key: str, value: Any, path: Path, fix: str) -> dict[str, Any]:
    """The ``spade`` entry of the checkpoint file ``path`` (:func:`checkpoint_info`), or one line naming ``key``: a
    file refused as unsafe (dangerous, not damaged: said so, with what it would have run) or not a checkpoint."""
    from spade.models.modelfile import UnsafeModelFileError  # heavy: spade.models imports diffusers

    try:
        return checkpoint_info(path)
    except UnsafeModelFileError as exc:
        raise ConfigError(f"{key}={value} was refused as unsafe (UnsafeModelFileError): {exc}") from None
    except Exception as exc:  # noqa: BLE001 - damaged or not a checkpoint: one line naming it
        raise ConfigError(f"{key}={value} is not a readable PyTorch checkpoint ({type(exc).__name__}); {fix}") from None


def check_shipped(key: str, path: Path) -> None:
    """A file SPADE ships (:mod:`spade.models.shipped`) must hash to its pin before a run rests on it."""
    from spade.models.shipped import SHIPPED, shipped_path  # heavy: spade.models imports diffusers

    for name, model in SHIPPED.items():
        if path.resolve() == model.path.resolve():
            try:
                shipped_path(name)
            except Exception as exc:  # noqa: BLE001 - missing or changed: one line naming the fix
                raise ConfigError(f"{key}={path}: {exc}") from None


def _a(word: str) -> str:
    return "an" if str(word)[:1].lower() in "aeiou" else "a"


def geometry_text(geo: Mapping[str, Any]) -> str:
    size = geo.get("image_size")
    text = f"{size[0]} x {size[1]} px" if size else "? px"
    if geo.get("resolution_m") is not None:
        text += f" at {float(geo['resolution_m']):g} m/px"
    if geo.get("frame") is not None:
        text += f", frame {json.dumps(geo['frame'], sort_keys=True)}"
    return text


def geometry_mismatch(ckpt: Mapping[str, Any], data: Mapping[str, Any]) -> list[str]:
    """The geometry keys (image_size, resolution_m, frame) on which a checkpoint's data and a dataset differ."""
    out = []
    if ckpt.get("image_size") is not None and data.get("image_size") is not None:
        if [int(v) for v in ckpt["image_size"]] != [int(v) for v in data["image_size"]]:
            out.append("image_size")
    if ckpt.get("resolution_m") is not None and data.get("resolution_m") is not None:
        if not math.isclose(float(ckpt["resolution_m"]), float(data["resolution_m"]), rel_tol=1e-6):
            out.append("resolution_m")
    if ckpt.get("frame") is not None and data.get("frame") is not None and ckpt["frame"] != data["frame"]:
        out.append("frame")
    return out


def check_geometry(key: str, value: Any, info: Mapping[str, Any] | None, cfg: DictConfig,
                   data_keys: tuple[str, ...]) -> None:
    """:func:`check_data_geometry` against a command's config (for the checks that take the config)."""
    check_data_geometry(key, value, info, read_options(cfg, DataSources), data_keys)


def check_data_geometry(key: str, value: Any, info: Mapping[str, Any] | None, sources: DataSources,
                        data_keys: tuple[str, ...]) -> None:
    """The checkpoint at ``key`` (its ``spade`` entry ``info``) was trained on windows of the geometry of each
    dataset ``data_keys`` (``train_dir``, ``test_dir``) holds or would be generated with."""
    if not info or not info.get("data"):
        return
    ckpt = info["data"]
    for data_key in data_keys:
        root = getattr(sources, data_key)
        if root is None:
            continue
        geo = data_geometry(root, getattr(sources, data_key.replace("_dir", "_generate")))
        if geo is None:
            continue
        diff = geometry_mismatch(ckpt, geo)
        if diff:
            raise ConfigError(
                f"{key}={value} was trained on {geometry_text(ckpt)} windows, data.{data_key}={geo['source']} holds "
                f"{geometry_text(geo)} ({', '.join(diff)} differ); use data at the checkpoint's geometry (its scale=) "
                "or a checkpoint trained on this data"
            )
