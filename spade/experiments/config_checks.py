"""Checks of a run's config before any MLflow run is opened or any data is generated.

:func:`validate_train_config` (called first thing by ``spade.train``) and :func:`validate_evaluate_config` (by
``spade.evaluate``) raise :class:`ConfigError` with one line naming the key, its value and the fix: wrong types
and ranges, a window too small to hold a manoeuvre, a checkpoint of the wrong role (a student given as
``model.margin.expert_ckpt``), a checkpoint whose window geometry differs from the data's, and an existing
dataset whose generation settings differ from the config's (:func:`spade.data.checks.check_dataset`, also run by
the data module's ``prepare_data``, so a dataset is never silently reused for other settings).
:func:`exit_on_user_error` turns these errors into one line on stderr and exit status 2 at the entry points
(``HYDRA_FULL_ERROR=1`` shows the traceback instead).
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from spade.data.checks import check_dataset, data_geometry
from spade.data.format import DatasetError
from spade.data.settings import dataset_settings
from spade.utils.errors import ConfigError, UserError, exit_on_errors

_MISSING = object()


# -- small typed getters ------------------------------------------------------------------------------------------
def _get(cfg: DictConfig, key: str) -> Any:
    try:
        value = OmegaConf.select(cfg, key, default=_MISSING, throw_on_missing=False)
        if OmegaConf.is_config(value):  # plain, resolved in the context of the whole config
            value = OmegaConf.to_container(value, resolve=True)
        return value
    except Exception as exc:  # an interpolation that cannot be resolved
        raise ConfigError(f"{key}: cannot be resolved ({exc}); fix the interpolation or set {key}=VALUE") from None


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _check_int(cfg: DictConfig, key: str, low: int | None = None, high: int | None = None, *, none_ok: bool = False,
               extra: tuple[int, ...] = (), fix: str = "") -> None:
    value = _get(cfg, key)
    if value is _MISSING or (value is None and none_ok):
        return
    rng = _range_text(low, high, extra)
    if not _is_int(value):
        raise ConfigError(f"{key}={value!r} is not an integer; set it to an integer {rng}{fix}")
    if value in extra:
        return
    if (low is not None and value < low) or (high is not None and value > high):
        raise ConfigError(f"{key}={value} is out of range; set it to an integer {rng}{fix}")


def _check_number(cfg: DictConfig, key: str, low: float | None = None, high: float | None = None, *,
                  low_open: bool = False, high_open: bool = False, none_ok: bool = False, fix: str = "") -> None:
    value = _get(cfg, key)
    if value is _MISSING or (value is None and none_ok):
        return
    lo = "" if low is None else f"{'>' if low_open else '>='} {low:g}"
    hi = "" if high is None else f"{'<' if high_open else '<='} {high:g}"
    rng = " and ".join(x for x in (lo, hi) if x)
    if not _is_number(value):
        raise ConfigError(f"{key}={value!r} is not a number; set it to a number {rng}{fix}")
    bad_low = low is not None and (value <= low if low_open else value < low)
    bad_high = high is not None and (value >= high if high_open else value > high)
    if bad_low or bad_high:
        raise ConfigError(f"{key}={value:g} is out of range; set it to a number {rng}{fix}")


def _check_choice(cfg: DictConfig, key: str, choices: list[str], *, none_ok: bool = False) -> None:
    value = _get(cfg, key)
    if value is _MISSING or (value is None and none_ok):
        return
    if value not in choices:
        raise ConfigError(f"{key}={value!r} is not one of {choices}; set {key}={choices[0]} (or another of them)")


def _range_text(low: int | None, high: int | None, extra: tuple[int, ...]) -> str:
    parts = []
    if low is not None:
        parts.append(f">= {low}")
    if high is not None:
        parts.append(f"<= {high}")
    text = " and ".join(parts)
    if extra:
        text += " (or " + " / ".join(str(e) for e in extra) + " for no limit)"
    return text


# -- checkpoints ----------------------------------------------------------------------------------------------------
def checkpoint_info(path: str | Path) -> dict[str, Any]:
    """The ``spade`` entry of a checkpoint (role, network config, window geometry, MLflow run id).

    Reads only that entry's plain values, through :func:`spade.models.modelfile.read_info` (``weights_only=True``,
    memory-mapped, so no tensor data is read and no code is run; a checkpoint that would run code is refused);
    ``{}`` for a checkpoint without the entry.
    """
    from spade.models.modelfile import read_info

    return read_info(path, checkpoint=True, required=False)


def _check_checkpoint(key: str, value: Any, role: str, fix: str) -> dict[str, Any] | None:
    """The ``spade`` entry of the checkpoint at config ``key``, checked to exist and to hold ``role``."""
    if value in (None, "", "???"):
        return None
    path = Path(str(value))
    if path.is_dir():
        raise ConfigError(f"{key}={value} is a directory, not a checkpoint file; {fix}")
    if not path.is_file():
        raise ConfigError(f"{key}={value} does not exist; {fix}")
    _check_shipped(key, path)
    from spade.models.modelfile import UnsafeModelFileError

    try:
        info = checkpoint_info(path)
    except UnsafeModelFileError as exc:  # dangerous, not damaged: say so, with what it would have run
        raise ConfigError(f"{key}={value} was refused as unsafe (UnsafeModelFileError): {exc}") from None
    except Exception as exc:
        raise ConfigError(f"{key}={value} is not a readable PyTorch checkpoint ({type(exc).__name__}); {fix}") from None
    have = info.get("role")
    if have != role:
        what = f"{_a(have)} {have} checkpoint" if have else "not a SPADE checkpoint (no 'spade' entry)"
        raise ConfigError(f"{key}={value} is {what}, this key takes {_a(role)} {role} checkpoint; {fix}")
    return info


def _check_shipped(key: str, path: Path) -> None:
    """A file SPADE ships (:mod:`spade.models.shipped`) must hash to its pin before a run rests on it."""
    from spade.models.shipped import SHIPPED, shipped_path

    for name, model in SHIPPED.items():
        if path.resolve() == model.path.resolve():
            try:
                shipped_path(name)
            except Exception as exc:  # noqa: BLE001 - missing or changed: one line naming the fix
                raise ConfigError(f"{key}={path}: {exc}") from None


def _a(word: str) -> str:
    return "an" if str(word)[:1].lower() in "aeiou" else "a"


def _geometry_text(geo: Mapping[str, Any]) -> str:
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


def _check_geometry(key: str, value: Any, info: Mapping[str, Any] | None, cfg: DictConfig,
                    data_keys: tuple[str, ...]) -> None:
    if not info or not info.get("data"):
        return
    ckpt = info["data"]
    for data_key in data_keys:
        root = _get(cfg, f"data.{data_key}")
        if root is _MISSING or root is None:
            continue
        generate = _get(cfg, f"data.{data_key.replace('_dir', '_generate')}")
        geo = data_geometry(root, None if generate is _MISSING else generate)
        if geo is None:
            continue
        diff = geometry_mismatch(ckpt, geo)
        if diff:
            raise ConfigError(
                f"{key}={value} was trained on {_geometry_text(ckpt)} windows, data.{data_key}={geo['source']} holds "
                f"{_geometry_text(geo)} ({', '.join(diff)} differ); use data at the checkpoint's geometry (its scale=) "
                "or a checkpoint trained on this data"
            )


# -- windows --------------------------------------------------------------------------------------------------------
def _low(value: Any) -> float:
    """The smallest value of a template range: ``[a, b]``, a number, or a dict of ranges."""
    if isinstance(value, Mapping):
        return min(_low(v) for v in value.values())
    if isinstance(value, (list, tuple)):
        return float(min(value))
    return float(value)


def check_window_holds_manoeuvre(settings: Mapping[str, Any], key: str) -> None:
    """Refuse a window too small for the shortest manoeuvre its templates can draw (plus the margins)."""
    window = settings.get("window") or {}
    size, res = window.get("size_px"), window.get("resolution_m")
    wkey = f"{key}.window.size_px" if key else "window.size_px"
    if not _is_int(size) or size < 8:
        raise ConfigError(f"{wkey}={size!r} is not a window size; set it to an integer >= 8 pixels (the tiny scale "
                          "uses 64, the paper 128)")
    if not _is_number(res) or res <= 0:
        rkey = f"{key}.window.resolution_m" if key else "window.resolution_m"
        raise ConfigError(f"{rkey}={res!r} must be a number > 0 metres per pixel (e.g. 0.1)")
    imported = (settings.get("rosbag") or {}).get("paths") or (settings.get("skipp") or {}).get("root")
    if settings.get("sketches") or imported:
        return  # demonstrations from outside the templates: their sizes are not known here
    margin = float(window.get("margin_m") or 0.0)
    shapes = settings.get("shape") or "L"
    shapes = [shapes] if isinstance(shapes, str) else list(shapes)
    for shape in shapes:
        tpl = ((settings.get("template") or {}).get(shape)) or {}
        if not tpl.get("leg_m") or not tpl.get("radius_m"):
            continue
        need = _low(tpl["leg_m"]) + _low(tpl["radius_m"])  # the shortest leg and its turn, end to end
        have = size * res - 2 * margin
        if have < need:
            px = max(8, math.ceil((need + 2 * margin) / res - 1e-9))
            raise ConfigError(
                f"{wkey}={size} is too small for a {shape} manoeuvre: {size} px x {res:g} m/px leaves {have:.2f} m "
                f"inside the {margin:g} m margins, the shortest {shape} (leg + turn radius) needs {need:.2f} m; use "
                f"{wkey} >= {px} (or a coarser window.resolution_m)"
            )


# -- the checks of an entry point -----------------------------------------------------------------------------------
def _model_role(cfg: DictConfig) -> str | None:
    target = str(_get(cfg, "model._target_") or "")
    if target.endswith("StudentModule"):
        return "student"
    if target.endswith("ExpertModule"):
        return "expert"
    return None


def _check_trainer(cfg: DictConfig) -> None:
    fix_epochs = ", e.g. trainer.max_epochs=2"
    _check_int(cfg, "trainer.max_epochs", 1, none_ok=True, extra=(-1,), fix=fix_epochs)
    _check_int(cfg, "trainer.max_steps", 1, none_ok=True, extra=(-1,), fix=", e.g. trainer.max_steps=100")
    if _get(cfg, "trainer.max_epochs") == -1 and _get(cfg, "trainer.max_steps") in (-1, None, _MISSING):
        raise ConfigError("trainer.max_epochs=-1 and trainer.max_steps=-1 never stop; set trainer.max_epochs=N")
    _check_int(cfg, "trainer.check_val_every_n_epoch", 1, none_ok=True)
    _check_int(cfg, "trainer.log_every_n_steps", 1, none_ok=True)
    _check_int(cfg, "trainer.accumulate_grad_batches", 1, none_ok=True)
    _check_int(cfg, "trainer.num_sanity_val_steps", 0, none_ok=True, extra=(-1,))
    _check_number(cfg, "trainer.gradient_clip_val", 0, none_ok=True)
    for key in ("limit_train_batches", "limit_val_batches", "limit_test_batches"):
        value = _get(cfg, f"trainer.{key}")
        if value is _MISSING or value is None:
            continue
        ok = (_is_int(value) and value >= 0) or (_is_number(value) and 0 <= value <= 1)
        if not ok:
            raise ConfigError(f"trainer.{key}={value!r} must be a fraction in [0, 1] or a whole number of batches >= 0")


def _check_data(cfg: DictConfig) -> None:
    _check_int(cfg, "data.batch_size", 1, fix=", e.g. data.batch_size=32")
    _check_int(cfg, "data.eval_batch_size", 1, none_ok=True)
    _check_int(cfg, "data.num_workers", 0, fix=" (0 loads in the main process)")
    _check_number(cfg, "data.val_fraction", 0, 1, high_open=True, fix=", e.g. data.val_fraction=0.15")
    _check_int(cfg, "data.split_seed", none_ok=True)
    _check_int(cfg, "data.max_train_instances", 1, none_ok=True)
    _check_int(cfg, "data.max_test_instances", 1, none_ok=True)
    for key in ("image_size", "train_instances", "test_instances", "transfer_instances", "batch_size"):
        _check_int(cfg, f"scale.{key}", 1, none_ok=True)
    _check_number(cfg, "scale.resolution_m", 0, low_open=True, none_ok=True)
    for name in ("train", "test"):
        _check_folder_path(f"data.{name}_dir", _get(cfg, f"data.{name}_dir"))
        generate = _get(cfg, f"data.{name}_generate")
        if generate is _MISSING or generate is None:
            continue
        root = _get(cfg, f"data.{name}_dir")
        settings = dataset_settings(Path(str(root)), generate)
        scaled = _get(cfg, "scale.annotate") not in (_MISSING, None)
        check_window_holds_manoeuvre(settings, "scale.annotate" if scaled else f"data.{name}_generate")
        _check_window_size(cfg, settings, "scale.annotate" if scaled else f"data.{name}_generate")
        _check_map_entries(cfg, name, settings.get("maps"))
        num = settings.get("num_instances")
        if num is not None and (not _is_int(num) or num < 1):
            raise ConfigError(f"data.{name}_generate num_instances={num!r} must be an integer >= 1; set "
                              f"scale.{name}_instances")


def _check_folder_path(key: str, value: Any) -> None:
    """A folder SPADE reads or creates: no part of its path may be an existing file."""
    if _unset(value):
        return
    path = Path(str(value)).expanduser()
    for part in (path, *path.parents):
        if part.exists():
            if not part.is_dir():
                raise ConfigError(f"{key}={value}: {part} is a file, not a folder; set paths.data_dir (or {key}) "
                                  "to a folder")
            return


def _check_map_entries(cfg: DictConfig, name: str, maps: Any) -> None:
    """Every map a dataset is generated from exists (a yaml, a folder of them or a ``kind:seed`` generator spec):
    an unknown entry is named before any work, never reported as a dataset "generated with other settings"."""
    if maps is None:
        return
    from spade.annotation.sources import expand_map_specs

    try:
        expand_map_specs(maps)
    except (FileNotFoundError, ValueError) as exc:
        where = "scale.train_maps" if name == "train" and _get(cfg, "scale.train_maps") not in (_MISSING, None) \
            else f"data.{name}_generate"
        raise ConfigError(f"{where}: {exc.args[0] if exc.args else exc}; fix that entry, e.g. warehouse:1 or the path "
                          "of a ROS map yaml (nothing was generated or changed)") from None


def model_downsampling(cfg: DictConfig) -> tuple[int, str] | None:
    """(the multiple every window side must be of, what says so) for the configured network, from its preset."""
    role = _model_role(cfg)
    try:
        if role == "student":
            from spade.models.student import STUDENT_PRESETS

            size = _get(cfg, "model.size")
            widths = STUDENT_PRESETS.get(size)
            what = f"model.size={size}"
        elif role == "expert":
            from spade.models.cond_expert import COND_EXPERT_PRESETS
            from spade.models.uncond_expert import UNCOND_EXPERT_PRESETS

            presets = COND_EXPERT_PRESETS if _get(cfg, "model.conditional") is not False else UNCOND_EXPERT_PRESETS
            preset = _get(cfg, "model.preset")
            widths = (presets.get(preset) or {}).get("widths")
            what = f"model.preset={preset}"
        else:
            return None
    except TypeError:  # an unhashable size or preset: _check_model names it
        return None
    if not widths:
        return None
    return 2 ** (len(widths) - 1), what


def _check_window_size(cfg: DictConfig, settings: Mapping[str, Any], key: str) -> None:
    """The data's window, ``scale.image_size`` and the U-Net's downsampling agree, before any data or prerequisite
    is made: ``scale.image_size`` alone does not resize the data, and a side the U-Net cannot halve fails only in
    the first forward pass."""
    window = settings.get("window") or {}
    size, res = window.get("size_px"), window.get("resolution_m")
    wkey = f"{key}.window.size_px"
    image_size = _get(cfg, "scale.image_size")
    if _is_int(image_size) and _is_int(size) and image_size != size:
        raise ConfigError(
            f"scale.image_size={image_size} differs from {wkey}={size}, the window the data are cut with (the "
            f"data would stay {size} px); set both: scale.image_size={image_size} {wkey}={image_size}"
        )
    scale_res = _get(cfg, "scale.resolution_m")
    if _is_number(scale_res) and _is_number(res) and not math.isclose(scale_res, res, rel_tol=1e-9):
        raise ConfigError(
            f"scale.resolution_m={scale_res:g} differs from {key}.window.resolution_m={res:g}, the data's metres per "
            f"pixel; set both: scale.resolution_m={scale_res:g} {key}.window.resolution_m={scale_res:g}"
        )
    found = model_downsampling(cfg)
    if found and _is_int(size) and size % found[0]:
        multiple, what = found
        lower, upper = size // multiple * multiple, (size // multiple + 1) * multiple
        raise ConfigError(
            f"{wkey}={size} is not a multiple of {multiple}, which the U-Net of {what} needs ({multiple} = 2^its "
            f"downsamplings); use a window of {lower or upper} or {upper} px (and scale.image_size to match)"
        )


def _check_model(cfg: DictConfig) -> None:
    from spade.models import presets

    role = _model_role(cfg)
    _check_number(cfg, "model.optimizer.lr", 0, low_open=True, fix=", e.g. 1e-3")
    _check_number(cfg, "model.optimizer.weight_decay", 0, none_ok=True)
    if role == "student":
        _check_choice(cfg, "model.size", presets("student"))
        _check_number(cfg, "model.bc_pos_weight", 0, low_open=True, none_ok=True, fix=" (null: plain BCE)")
        _margin_config(cfg)  # model.margin's options, by MarginConfig's own checks (lambda_dm >= 0, expert kind...)
    elif role == "expert":
        kind = "cond_expert" if _get(cfg, "model.conditional") is not False else "uncond_expert"
        _check_choice(cfg, "model.preset", presets(kind))
        _check_number(cfg, "model.ema_decay", 0, 1, high_open=True)
        _check_choice(cfg, "model.sampler", ["ddim", "ddpm"])
        _check_int(cfg, "model.num_inference_steps", 1)
        _check_int(cfg, "model.num_train_timesteps", 2)


def _margin_config(cfg: DictConfig) -> Any:
    """``model.margin`` as a :class:`~spade.training.margin.MarginConfig` (None without a margin): its checks are
    MarginConfig's, reported as one line naming ``model.margin.<option>``."""
    from spade.training.margin import MarginConfig, MarginOptionError

    options = _get(cfg, "model.margin")
    if options in (_MISSING, None):
        return None
    if not isinstance(options, Mapping):
        raise ConfigError(f"model.margin={options!r} is not a group of margin options; choose margin=none, "
                          "margin=dbc or margin=cond_dbc")
    try:
        return MarginConfig.from_options(options)
    except MarginOptionError as exc:
        raise ConfigError(exc.at("model.margin.")) from None


def _check_checkpoints(cfg: DictConfig) -> None:
    role = _model_role(cfg)
    train_data = ("train_dir", "test_dir")
    ckpt = _get(cfg, "ckpt_path")
    if isinstance(ckpt, str) and not ckpt.strip():
        raise ConfigError("ckpt_path='' is empty; pass checkpoints/last.ckpt of an interrupted run to resume it, or "
                          "leave ckpt_path unset (ckpt_path=null) to start a new run")
    if ckpt is not _MISSING and role is not None:
        fix = "pass checkpoints/last.ckpt of an interrupted run of this experiment (under its logs/runs/ folder)"
        info = _check_checkpoint("ckpt_path", ckpt, role, fix)
        _check_geometry("ckpt_path", ckpt, info, cfg, train_data)
        _check_resume(cfg, ckpt, info)
    init = _get(cfg, "model.init_ckpt")
    if init is not _MISSING:
        info = _check_checkpoint("model.init_ckpt", init, "student",
                                 "pass a student checkpoint (the pretrained student of the fine-tuning row)")
        _check_geometry("model.init_ckpt", init, info, cfg, train_data)
    expert = _get(cfg, "model.margin.expert_ckpt")
    if expert is not _MISSING:
        info = _check_checkpoint("model.margin.expert_ckpt", expert, "expert",
                                 "pass an expert checkpoint (from an expert_* experiment), or leave it null so that "
                                 "the experiment's requires.expert finds or trains one")
        _check_geometry("model.margin.expert_ckpt", expert, info, cfg, train_data)
        _check_expert_kind(cfg, expert, info)


# What a resumed run must share with the run its checkpoint was written under: (config key, MLflow parameter).
RESUME_KEYS = (("run_name", "cfg/run_name"), ("seed", "cfg/seed"), ("model.size", "cfg/model/size"),
               ("scale.name", "cfg/scale/name"))


def _check_resume(cfg: DictConfig, ckpt: Any, info: dict[str, Any] | None) -> None:
    """``ckpt_path`` resumes the MLflow run the checkpoint was written under. Refused before any work (so that no
    command changes a run it did not start): a run this store does not hold, a FINISHED run, and a checkpoint of
    another row, seed, size or scale (each named with both values)."""
    if _get(cfg, "train") not in (True, _MISSING) or not ckpt:
        return  # train=false: the checkpoint's weights are tested, nothing is resumed
    run_id = (info or {}).get("mlflow_run_id")
    uri = _get(cfg, "logger.mlflow.tracking_uri")
    if not run_id or _unset(uri):
        return  # written without MLflow, or MLflow off: nothing to continue
    uri = str(uri)
    new_run = ("start a new run instead (drop ckpt_path" + (", or start from its weights with model.init_ckpt="
                                                              f"{ckpt}" if _model_role(cfg) == "student" else "") + ")")
    path = _store_path(uri)
    if path is not None and not path.exists():
        raise ConfigError(f"ckpt_path={ckpt} was written under MLflow run {run_id}, but there is no store at {uri}; "
                          f"resume with the store it was logged to (SPADE_HOME or paths.mlflow_tracking_uri), or "
                          f"{new_run}")
    from mlflow import MlflowClient  # the store itself was checked by validate_train_config (_check_logger_store)

    try:
        run = MlflowClient(tracking_uri=uri).get_run(run_id)
    except Exception:  # noqa: BLE001 - not in this store (or unreachable): say which run and where
        raise ConfigError(f"ckpt_path={ckpt} was written under MLflow run {run_id}, which the store {uri} does not "
                          f"hold; resume with the store it was logged to (SPADE_HOME or paths.mlflow_tracking_uri), "
                          f"or {new_run}") from None
    name = run.info.run_name
    if run.info.status == "FINISHED":
        raise ConfigError(f"ckpt_path={ckpt} belongs to run {name!r} ({run_id}), which FINISHED: a resume would log "
                          f"into a finished run; {new_run}")
    params = run.data.params
    differ = [f"{key}: checkpoint's run {params[param]!r}, this config {str(_get(cfg, key))!r}"
              for key, param in RESUME_KEYS
              if param in params and _get(cfg, key) is not _MISSING and params[param] != str(_get(cfg, key))]
    if differ:
        raise ConfigError(f"ckpt_path={ckpt} is a checkpoint of run {name!r} ({run_id}), not of this experiment "
                          f"({'; '.join(differ)}); resume it with the config it was started with (+experiment="
                          f"{params.get('cfg/run_name', name)} and the same overrides), or {new_run}")


def _check_expert_kind(cfg: DictConfig, expert: Any, info: dict[str, Any] | None) -> None:
    """DBC needs an unconditional expert, Cond-DBC a conditional one (``model.margin.expert``; the check is
    :meth:`MarginConfig.check_expert`, which the student runs on the loaded expert too)."""
    from spade.training.errors import ExpertMismatchError

    net_role = ((info or {}).get("config") or {}).get("role")
    config = _margin_config(cfg)
    if net_role not in ("cond_expert", "uncond_expert") or config is None:
        return
    try:
        config.check_expert(net_role == "cond_expert", f"model.margin.expert_ckpt={expert}")
    except ExpertMismatchError as exc:
        raise ConfigError(str(exc)) from None


def _check_logger_store(cfg: DictConfig) -> None:
    """The store a run logs to, when it is an existing SQLite file, must be an MLflow store
    (:func:`check_store_file`): someone else's database is never written."""
    uri = _get(cfg, "logger.mlflow.tracking_uri")
    if not _unset(uri):
        check_store_file("logger.mlflow.tracking_uri", str(uri))


def _check_bool(cfg: DictConfig, key: str) -> None:
    """The one boolean check of every entry point: ``true`` / ``false`` (null or unset: the default), nothing else
    (Hydra reads ``maybe`` or ``1`` as a string or a number, which Python would take as true)."""
    value = _get(cfg, key)
    if value is not _MISSING and value is not None and not isinstance(value, bool):
        raise ConfigError(f"{key}={value!r} is not a boolean; set {key}=true or {key}=false")


def validate_train_config(cfg: DictConfig) -> None:
    """Every check of ``spade.train``'s config that needs no training: raises :class:`ConfigError` (one line)."""
    _check_int(cfg, "seed", 0, 2**32 - 1, none_ok=True, fix=", e.g. seed=42")
    _check_choice(cfg, "prerequisites", ["train", "error"])
    for key in ("train", "test", "test_untrained"):
        _check_bool(cfg, key)
    _check_logger_store(cfg)
    metric = _get(cfg, "optimized_metric")
    if metric not in (_MISSING, None) and not isinstance(metric, str):
        raise ConfigError(f"optimized_metric={metric!r} must be a metric name such as val/loss_bc")
    _check_trainer(cfg)
    _check_data(cfg)
    _check_model(cfg)
    _check_checkpoints(cfg)
    for name in ("train", "test"):
        check_dataset(_dir(cfg, f"data.{name}_dir"), _opt(cfg, f"data.{name}_generate"), f"data.{name}_dir")


def validate_evaluate_config(cfg: DictConfig) -> None:
    """``spade.evaluate``'s checks: the checkpoint's role, and its geometry against the data it is tested on."""
    ckpt = _get(cfg, "ckpt_path")
    fix = "pass a student or expert checkpoint written by python -m spade.train"
    if ckpt in (_MISSING, None, "", "???"):
        raise ConfigError(f"ckpt_path is not set; {fix} (ckpt_path=PATH)")
    path = Path(str(ckpt))
    if not path.exists():
        raise ConfigError(f"ckpt_path={ckpt} does not exist; {fix}")
    if path.is_dir():
        raise ConfigError(f"ckpt_path={ckpt} is a directory, not a checkpoint file; {fix}")
    from spade.models.modelfile import UnsafeModelFileError

    try:
        info = checkpoint_info(path)
    except UnsafeModelFileError as exc:
        raise ConfigError(f"ckpt_path={ckpt} was refused as unsafe (UnsafeModelFileError): {exc}") from None
    except Exception as exc:  # noqa: BLE001 - damaged or not a checkpoint: one line naming it
        raise ConfigError(f"ckpt_path={ckpt} is not a readable PyTorch checkpoint ({type(exc).__name__}); "
                          f"{fix}") from None
    if info.get("role") not in ("student", "expert"):
        raise ConfigError(f"ckpt_path={ckpt} is not a SPADE student or expert checkpoint (role "
                          f"{info.get('role')!r}); {fix}")
    _check_logger_store(cfg)
    _check_data(cfg)
    for name in ("train", "test"):
        check_dataset(_dir(cfg, f"data.{name}_dir"), _opt(cfg, f"data.{name}_generate"), f"data.{name}_dir")
    _check_geometry("ckpt_path", ckpt, info, cfg, ("test_dir", "train_dir"))


def _opt(cfg: DictConfig, key: str) -> Any:
    value = _get(cfg, key)
    return None if value is _MISSING else value


def _dir(cfg: DictConfig, key: str) -> str | None:
    value = _opt(cfg, key)
    return None if value in (None, "") else str(value)


def validate_checkpoints(cfg: DictConfig) -> None:
    """The role, kind and geometry checks of every checkpoint a run names (``ckpt_path``, ``model.init_ckpt``,
    ``model.margin.expert_ckpt``), again after the prerequisites filled paths from the Model Registry: a
    fetched model passes the same checks as one given by path."""
    _check_checkpoints(cfg)


# -- the other entry points ---------------------------------------------------------------------------------------
MODEL_SUFFIXES = (".ckpt", ".onnx", ".pt")


def _unset(value: Any) -> bool:
    return value is _MISSING or value in (None, "", "???")


def _same_file(a: Path, b: Path) -> bool:
    try:
        if a.exists() and b.exists():
            return os.path.samefile(a, b)
        return a.expanduser().resolve() == b.expanduser().resolve()
    except OSError:
        return False


def _input_file(key: str, value: Any, fix: str, suffixes: tuple[str, ...] = ()) -> Path:
    """An input file named at ``key``: set, existing, a file (not a folder), with one of ``suffixes``."""
    if _unset(value):
        raise ConfigError(f"{key} is not set; {fix}")
    path = Path(str(value)).expanduser()
    if suffixes and path.suffix.lower() not in suffixes:
        raise ConfigError(f"{key}={value} is not a model file ({' / '.join(suffixes)}); {fix}")
    if path.is_dir():
        raise ConfigError(f"{key}={value} is a directory, not a file; {fix}")
    if not path.exists():
        raise ConfigError(f"{key}={value} does not exist; {fix}")
    return path


def _output_file(key: str, value: Any, inputs: Mapping[str, Path | None], fix: str,
                 suffixes: tuple[str, ...] = (), overwrite: Any = _MISSING) -> Path:
    """An output file at ``key``: not a folder, not one of the ``inputs``, and, when it exists, replaced only with
    ``overwrite=true`` and only when SPADE wrote it (:mod:`spade.deploy.outputs`)."""
    path = Path(str(value)).expanduser()
    if path.is_dir():
        raise ConfigError(f"{key}={value} is a directory; give the path of a file to write ({fix})")
    for in_key, in_path in inputs.items():
        if in_path is not None and _same_file(path, in_path):
            raise ConfigError(f"{key}={value} is the input {in_key}: writing it would overwrite that file; {fix}")
    if suffixes and path.suffix.lower() not in suffixes:
        raise ConfigError(f"{key}={value} must end with {' or '.join(suffixes)}; {fix}")
    from spade.deploy.outputs import replace_refusal

    if (refusal := replace_refusal(key, path, overwrite is True)) is not None:
        raise ConfigError(refusal)
    return path


def _map_files(key: str, spec: Any) -> list[Path]:
    """The files of a map argument (a ROS yaml and its image; none for a procedural ``kind:seed``), checked."""
    from spade.annotation.sources import parse_procedural

    fix = "give a ROS map yaml (map_server format) or a generator spec such as warehouse:101"
    if _unset(spec):
        raise ConfigError(f"{key} is not set; {fix}")
    try:
        if parse_procedural(str(spec)) is not None:
            return []
    except ValueError as exc:
        raise ConfigError(f"{key}={spec}: {exc}") from None
    path = _input_file(key, spec, fix)
    from spade.maps.ros_io import MapFormatError, read_map_yaml

    try:
        meta = read_map_yaml(path)
    except MapFormatError as exc:
        raise ConfigError(f"{key}={spec}: {exc}") from None
    return [path, Path(meta.image_path)]


def _point(cfg: DictConfig, key: str, n: int, example: str) -> list[float]:
    value = _get(cfg, key)
    fix = f"pass {key}={example} (map-frame metres{', yaw in radians' if n == 3 else ''})"
    if _unset(value):
        raise ConfigError(f"{key} is not set; {fix}")
    if not isinstance(value, (list, tuple)) or len(value) != n or not all(_is_number(v) for v in value):
        raise ConfigError(f"{key}={value!r} is not {n} finite numbers; {fix}")
    return [float(v) for v in value]


def validate_annotate_config(cfg: Mapping[str, Any] | DictConfig) -> None:
    """``spade.annotate``'s checks before any map is loaded: the output (never a file or a folder that is not a
    SPADE dataset, an existing dataset only with ``overwrite=true``), the sources, numbers and the window."""
    from spade.data.writer import check_output_dir

    cfg = cfg if isinstance(cfg, DictConfig) else OmegaConf.create(dict(cfg))
    if _unset(_get(cfg, "out_dir")):
        raise ConfigError("out_dir is not set; pass out_dir=FOLDER (a new folder, or a dataset with overwrite=true)")
    _check_bool(cfg, "overwrite")
    overwrite = _get(cfg, "overwrite")
    out_dir = Path(str(_get(cfg, "out_dir"))).expanduser()
    check_output_dir(out_dir, bool(overwrite))
    _check_int(cfg, "seed", 0, 2**32 - 1, fix=", e.g. seed=0")
    _check_int(cfg, "workers", 0, fix=" (0 or 1: in this process)")
    _check_choice(cfg, "start_method", ["spawn", "forkserver", "fork"])
    _check_int(cfg, "num_waypoints", 2, fix=", e.g. num_waypoints=64")
    sketches = _get(cfg, "sketches")
    rosbag = _get(cfg, "rosbag.paths")
    skipp = _get(cfg, "skipp.root")
    if not _unset(sketches):
        path = _input_file("sketches", sketches, "give a sketch file written by python -m spade.sketch (sketches.yaml)")
        if _same_file(path.parent, out_dir) or out_dir in path.parents:
            raise ConfigError(f"out_dir={out_dir} holds the input sketches={sketches}; choose another out_dir")
        from spade.annotation.sketch_file import SketchFileError, load_sketch_file

        try:
            load_sketch_file(path)  # parsed and validated before any map is loaded or any instance made
        except SketchFileError as exc:
            raise ConfigError(f"sketches={sketches}: {exc}") from None
    elif not _unset(rosbag):
        for item in rosbag if isinstance(rosbag, list) else [rosbag]:
            if not Path(str(item)).expanduser().exists():
                raise ConfigError(f"rosbag.paths entry {item} does not exist; give rosbag2 folders (or .mcap / .db3)")
    elif not _unset(skipp):
        if not Path(str(skipp)).expanduser().is_dir():
            raise ConfigError(f"skipp.root={skipp} is not a folder; give the folder of SKIPP's published dataset")
    else:
        _check_int(cfg, "num_instances", 1, fix=", e.g. num_instances=200")
        shapes = _get(cfg, "shape")
        from spade.annotation.templates import SHAPES

        for shape in shapes if isinstance(shapes, list) else [shapes]:
            if shape not in SHAPES:
                raise ConfigError(f"shape={shape!r} is not one of {list(SHAPES)}; use shape=L, shape=U or shape=[L,U]")
        from spade.annotation.sources import expand_map_specs

        try:
            expand_map_specs(_get(cfg, "maps"))
        except (ValueError, FileNotFoundError) as exc:
            raise ConfigError(f"maps={_get(cfg, 'maps')}: {exc}; give a folder of ROS map yamls, yaml paths or specs "
                              "such as warehouse:1") from None
    settings = OmegaConf.to_container(cfg, resolve=True) if isinstance(cfg, DictConfig) else dict(cfg)
    check_window_holds_manoeuvre(settings, "")


def validate_export_config(cfg: DictConfig) -> None:
    """``spade.export``'s checks: a student checkpoint file in, an output that is not the checkpoint (nor a folder)."""
    from spade.deploy.export import SUFFIXES

    fix = "pass the student checkpoint (.ckpt) written by python -m spade.train"
    ckpt = _input_file("ckpt_path", _get(cfg, "ckpt_path"), fix)
    _check_checkpoint("ckpt_path", str(ckpt), "student", fix)
    _check_choice(cfg, "format", list(SUFFIXES))
    fmt = _get(cfg, "format")
    fmt = "onnx" if fmt in (_MISSING, None) else fmt
    _check_bool(cfg, "overwrite")
    overwrite = _get(cfg, "overwrite")
    out = _get(cfg, "out_path")
    suffix = SUFFIXES[fmt]
    if _unset(out):
        default = ckpt.with_suffix(suffix)
        if _same_file(default, ckpt):
            raise ConfigError(f"ckpt_path={ckpt} ends with {suffix}: format={fmt} would write its export onto the "
                              f"checkpoint itself; set out_path={ckpt.with_name(ckpt.stem + '.' + fmt + suffix)}")
    else:
        _output_file("out_path", out, {"ckpt_path": ckpt}, f"set out_path to a new {suffix} file", (suffix,),
                     overwrite)
    _check_int(cfg, "opset", 7, fix=", e.g. opset=17")
    _check_int(cfg, "parity_batch", 1)
    _check_int(cfg, "latency_runs", 0)
    _check_int(cfg, "threads", 1, none_ok=True, fix=" (null: all cores)")
    _check_number(cfg, "tolerance", 0, none_ok=True, fix=" (null: only report)")
    report = _get(cfg, "report_path")
    if not _unset(report):
        _output_file("report_path", report, {"ckpt_path": ckpt}, "give a new .json file", overwrite=overwrite)


def validate_plan_config(cfg: DictConfig) -> None:
    """``spade.plan``'s checks: the map and model files, a robot pose and a goal that differ, and a picture path
    that is none of the inputs."""
    maps = _map_files("map", _get(cfg, "map"))
    model = _input_file("model_path", _get(cfg, "model_path"),
                        "pass model=PATH (a student .ckpt from python -m spade.train or its .onnx / .pt export) or set "
                        "SPADE_PLANNER_MODEL", MODEL_SUFFIXES)
    if model.suffix.lower() == ".ckpt":
        _check_checkpoint("model_path", str(model), "student", "pass a student checkpoint (an expert does not plan)")
    start = _point(cfg, "start", 3, "X,Y,YAW")
    goal = _point(cfg, "goal", 2, "X,Y")
    if math.hypot(goal[0] - start[0], goal[1] - start[1]) < 1e-9:
        raise ConfigError(f"goal={goal[0]:g},{goal[1]:g} is the robot's own position (start); give a goal elsewhere")
    inputs = {"model_path": model, **{("map" if i == 0 else "the map's image"): p for i, p in enumerate(maps)}}
    _check_bool(cfg, "overwrite")
    _output_file("out", _get(cfg, "out"), inputs, "set out=plan.png (a new picture file)", (".png",),
                 _get(cfg, "overwrite"))
    _check_choice(cfg, "planner.far_goal", ["fail", "clip"])
    _check_number(cfg, "planner.threshold", 0, 1, low_open=True, high_open=True)
    _check_int(cfg, "planner.num_waypoints", 2)
    _check_number(cfg, "picture.context_m", 0)
    _check_int(cfg, "picture.width_px", 16)


def _store_path(uri: str) -> Path | None:
    """The local path of an MLflow store URI (sqlite:///..., file:..., a plain path); None for a server."""
    if uri.startswith("sqlite:"):
        rest = uri[len("sqlite:"):]
        return Path(rest[3:] if rest.startswith("///") else rest.lstrip("/"))
    if uri.startswith("file:"):
        from urllib.parse import urlparse

        return Path(urlparse(uri).path)
    if "://" in uri:
        return None  # http(s), databricks, ...: the server answers for itself
    return Path(uri)


def check_store_file(key: str, uri: str) -> None:
    """An existing SQLite store at ``uri`` must be an MLflow store: read-only, before MLflow opens it (MLflow
    creates its tables in any SQLite file it is given, so a reader would write into someone else's database)."""
    import sqlite3

    path = _store_path(uri)
    if path is None or not uri.startswith("sqlite:") or not path.is_file():
        return
    try:
        db = sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=30)
        try:
            tables = {row[0] for row in db.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        finally:
            db.close()
    except sqlite3.DatabaseError as exc:
        raise ConfigError(f"{key}={uri}: {path} is not an SQLite database ({exc}); point {key} (or SPADE_HOME / "
                          "MLFLOW_TRACKING_URI) at the MLflow store the runs were logged to") from None
    missing = {"experiments", "runs", "metrics", "alembic_version"} - tables
    if missing:
        raise ConfigError(f"{key}={uri}: {path} is an SQLite database but not an MLflow store (no "
                          f"{', '.join(sorted(missing))} table); it is left untouched. Point {key} (or SPADE_HOME / "
                          "MLFLOW_TRACKING_URI) at the MLflow store the runs were logged to")


def validate_bench_config(cfg: DictConfig, known_sections: Sequence[str]) -> None:
    """``spade.bench``'s checks before any section runs: ``quick`` a boolean, ``sections`` among ``known_sections``
    (:data:`spade.perf.bench.SECTIONS`, passed in: the benchmark sits on a higher floor), a thread count."""
    _check_bool(cfg, "quick")
    sections = _get(cfg, "sections")
    if sections is not _MISSING and sections is not None:
        if isinstance(sections, str) or not isinstance(sections, list):
            raise ConfigError(f"sections={sections!r} is not a list; use sections=[{','.join(list(known_sections)[:2])}]")
        unknown = sorted({str(x) for x in sections} - set(known_sections))
        if unknown:
            raise ConfigError(f"sections: unknown {', '.join(unknown)}; use sections=[...] with some of "
                              f"{', '.join(known_sections)}")
    _check_int(cfg, "threads", 1, none_ok=True, fix=" (null: all cores)")


def validate_report_config(cfg: DictConfig) -> None:
    """``spade.report``'s checks: the table exists and the MLflow store is there (a missing one would be created
    empty and every row reported missing)."""
    from spade.experiments.tables import get_table

    table = _get(cfg, "table")
    if str(table) != "all":
        try:
            get_table(table)
        except (KeyError, ValueError) as exc:
            raise ConfigError(f"table={table}: {exc.args[0] if exc.args else exc}") from None
    uri = _get(cfg, "tracking_uri")
    if _unset(uri):
        raise ConfigError("tracking_uri is not set; pass tracking_uri=sqlite:///PATH/logs/mlflow.db")
    path = _store_path(str(uri))
    if path is not None and not path.exists():
        raise ConfigError(f"tracking_uri={uri}: there is no MLflow store at {path} (reporting would create an empty "
                          "one); point tracking_uri (or SPADE_HOME / MLFLOW_TRACKING_URI) at the store the runs were "
                          "logged to")
    if path is not None and str(uri).startswith("sqlite:") and path.is_dir():
        raise ConfigError(f"tracking_uri={uri}: {path} is a directory, not an MLflow SQLite store; point it at the "
                          "store file, e.g. sqlite:///PATH/logs/mlflow.db")
    check_store_file("tracking_uri", str(uri))
    out = _get(cfg, "output_dir")
    if not _unset(out) and Path(str(out)).is_file():
        raise ConfigError(f"output_dir={out} is a file; give a folder for the report files")


def validate_sketch_config(cfg: DictConfig) -> None:
    """``spade.sketch``'s checks before the server starts: map, port, model file, output folder and window."""
    _map_files("map", _get(cfg, "map"))
    _check_int(cfg, "port", 1, 65535, fix=", e.g. port=8765")
    host = _get(cfg, "host")
    if not isinstance(host, str) or not host:
        raise ConfigError(f"host={host!r} is not an address; use host=127.0.0.1")
    model = _get(cfg, "model_path")
    if not _unset(model):
        path = _input_file("model_path", model, "pass model=PATH: a student .ckpt or its .onnx / .pt export",
                           MODEL_SUFFIXES)
        if path.suffix.lower() == ".ckpt":
            _check_checkpoint("model_path", str(path), "student",
                              "pass a student checkpoint (an expert does not plan)")
    out = _get(cfg, "out_dir")
    if not _unset(out) and Path(str(out)).expanduser().is_file():
        raise ConfigError(f"out_dir={out} is a file; give a folder for sketches.yaml and dataset/")
    for key in ("models", "allowed_hosts"):
        value = _get(cfg, key)
        if value not in (_MISSING, None) and not isinstance(value, list):
            raise ConfigError(f"{key}={value!r} must be a list, e.g. {key}=[a,b]")
    for folder in _get(cfg, "models") if isinstance(_get(cfg, "models"), list) else []:
        if not Path(str(folder)).expanduser().is_dir():
            raise ConfigError(f"models entry {folder} is not a folder; give folders that hold model files")
    from spade.sketching.workspace import annotation_config

    overrides = _get(cfg, "annotate")
    from spade.sketching.app import flatten_overrides

    try:
        settings = annotation_config(flatten_overrides(overrides) if isinstance(overrides, Mapping) else [])
    except Exception as exc:  # noqa: BLE001 - an override Hydra cannot apply
        raise ConfigError(f"annotate: {exc}".replace("\n", " ")) from None
    check_window_holds_manoeuvre(settings, "annotate")


# -- reporting ------------------------------------------------------------------------------------------------------
def user_errors() -> tuple[type[BaseException], ...]:
    """Exceptions that mean the user must change something (reported without a traceback): every package's user
    errors derive from :class:`spade.utils.errors.UserError`."""
    return (UserError,)


def exit_on_user_error(fn: Callable[..., Any]) -> Callable[..., Any]:
    """Wrap an entry point's task function: a user error (:func:`user_errors`) ends the process with one line and
    exit status 2.

    ``HYDRA_FULL_ERROR=1`` re-raises it instead, for Hydra's full traceback.
    """
    return exit_on_errors(user_errors)(fn)
