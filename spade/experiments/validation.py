"""Checks of a run's config before any MLflow run is opened or any data is generated.

:func:`validate_train_config` (called first thing by ``spade.train``) and :func:`validate_evaluate_config` (by
``spade.evaluate``) raise :class:`ConfigError` with one line naming the key, its value and the fix: wrong types
and ranges, a window too small to hold a manoeuvre, a checkpoint of the wrong role (a student given as
``model.guidance.expert_ckpt``), a checkpoint whose window geometry differs from the data's, and an existing
dataset whose generation settings differ from the config's (:func:`check_dataset`, also run by the data module's
``prepare_data``, so a dataset is never silently reused for other settings). :func:`exit_on_user_error` turns
these errors into one line on stderr and exit status 2 at the entry points (``HYDRA_FULL_ERROR=1`` shows the
traceback instead).
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import os
import sys
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from spade.data.format import MANIFEST, DatasetError


class ConfigError(ValueError):
    """A user error in the config, reported as one line (key, value, fix) without a traceback."""


class DatasetSettingsError(ConfigError, DatasetError):
    """An existing dataset made with other settings than the config asks for (or not a dataset at all)."""


_MISSING = object()

# Annotation settings that never change a dataset's bytes (where it goes, how fast, the preview picture).
NON_SHAPING_KEYS = frozenset({"out_dir", "overwrite", "workers", "start_method", "progress", "preview", "hydra"})


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

    Reads only that entry's plain values: the file is opened safely by :func:`spade.models.modelfile.load_checkpoint`
    (``weights_only=True``, memory-mapped, so no tensor data is read and no code is run; a checkpoint that would
    run code is refused).
    """
    from spade.models.modelfile import load_checkpoint

    checkpoint = load_checkpoint(path, mmap=True)
    info = checkpoint.get("spade") if isinstance(checkpoint, dict) else None
    return dict(info) if isinstance(info, Mapping) else {}


def _check_checkpoint(key: str, value: Any, role: str, fix: str) -> dict[str, Any] | None:
    """The ``spade`` entry of the checkpoint at config ``key``, checked to exist and to hold ``role``."""
    if value in (None, "", "???"):
        return None
    path = Path(str(value))
    if not path.is_file():
        raise ConfigError(f"{key}={value} does not exist; {fix}")
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


# -- datasets -------------------------------------------------------------------------------------------------------
def _annotation_settings(root: Path, generate: Any) -> dict[str, Any]:
    from spade.annotation.run import annotation_config

    return OmegaConf.to_container(annotation_config(root, generate), resolve=True)


def _flatten(value: Any, prefix: str = "") -> Iterator[tuple[str, Any]]:
    if isinstance(value, Mapping):
        for k, v in value.items():
            yield from _flatten(v, f"{prefix}{k}.")
    else:
        yield prefix[:-1], value


def shaping_settings(settings: Mapping[str, Any]) -> dict[str, Any]:
    """The annotation settings that shape a dataset's bytes, flattened (``window.size_px`` ...)."""
    kept = {k: v for k, v in settings.items() if k not in NON_SHAPING_KEYS}
    return {k: json.loads(json.dumps(v, default=str)) for k, v in _flatten(kept)}


def settings_fingerprint(settings: Mapping[str, Any]) -> str:
    """A short hash of the shaping settings (what ``data.*_generate`` asks for or a manifest's ``generator``)."""
    blob = json.dumps(shaping_settings(settings), sort_keys=True, default=str).encode()
    return hashlib.sha256(blob).hexdigest()[:10]


def settings_difference(recorded: Mapping[str, Any], wanted: Mapping[str, Any]) -> dict[str, tuple[Any, Any]]:
    """{key: (recorded value, wanted value)} for every shaping setting that differs (missing -> None)."""
    a, b = shaping_settings(recorded), shaping_settings(wanted)
    return {k: (a.get(k), b.get(k)) for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)}


def _read_manifest_json(root: Path) -> dict[str, Any]:
    try:
        return json.loads((root / MANIFEST).read_text())
    except (OSError, ValueError) as exc:
        raise DatasetSettingsError(
            f"{root / MANIFEST} cannot be read ({exc}); delete {root} to regenerate it"
        ) from None


def check_dataset(root: str | Path | None, generate: Any, key: str = "data.train_dir") -> None:
    """Refuse an existing dataset at ``root`` that ``generate`` (a data config's ``*_generate``) would not make.

    Missing: fine (``prepare_data`` builds it). A folder without ``manifest.json``: not a dataset (a writer never
    leaves one). A manifest whose ``generator`` records other shaping settings: the keys that differ are named,
    with both values; the dataset is never reused for settings that did not make it.
    """
    if root is None:
        return
    root = Path(str(root))
    if not root.exists():
        return
    if not (root / MANIFEST).is_file():
        raise DatasetSettingsError(
            f"{key}={root} exists but holds no {MANIFEST} (not a complete SPADE dataset): delete the folder to "
            f"have it regenerated, or point {key} at another folder"
        )
    if generate is None:
        return
    recorded = _read_manifest_json(root).get("generator") or {}
    wanted = _annotation_settings(root, generate)
    diff = settings_difference(recorded, wanted)
    if diff:
        shown = "; ".join(f"{k}: dataset {a!r}, config {b!r}" for k, (a, b) in list(diff.items())[:8])
        more = f" (and {len(diff) - 8} more)" if len(diff) > 8 else ""
        raise DatasetSettingsError(
            f"{key}={root} was generated with other settings (dataset {settings_fingerprint(recorded)}, config "
            f"{settings_fingerprint(wanted)}): {shown}{more}. Delete {root} to regenerate it, or set paths.data_dir "
            f"(or {key}) to another folder"
        )


def data_geometry(root: str | Path | None, generate: Any) -> dict[str, Any] | None:
    """Window geometry of a dataset: from its manifest when it exists, else from the settings that will make it."""
    if root is None:
        return None
    root = Path(str(root))
    if (root / MANIFEST).is_file():
        manifest = _read_manifest_json(root)
        return {"image_size": manifest.get("image_size"), "resolution_m": manifest.get("resolution"),
                "frame": manifest.get("frame"), "source": str(root)}
    if generate is None:
        return None
    settings = _annotation_settings(root, generate)
    size = int(settings["window"]["size_px"])
    return {"image_size": [size, size], "resolution_m": float(settings["window"]["resolution_m"]), "frame": None,
            "source": f"{root} (to be generated)"}


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
    wkey = f"{key}.window.size_px"
    if not _is_int(size) or size < 8:
        raise ConfigError(f"{wkey}={size!r} is not a window size; set it to an integer >= 8 pixels (the tiny scale "
                          "uses 64, the paper 128)")
    if not _is_number(res) or res <= 0:
        raise ConfigError(f"{key}.window.resolution_m={res!r} must be a number > 0 metres per pixel (e.g. 0.1)")
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
        generate = _get(cfg, f"data.{name}_generate")
        if generate is _MISSING or generate is None:
            continue
        root = _get(cfg, f"data.{name}_dir")
        settings = _annotation_settings(Path(str(root)), generate)
        scaled = _get(cfg, "scale.annotate") not in (_MISSING, None)
        check_window_holds_manoeuvre(settings, "scale.annotate" if scaled else f"data.{name}_generate")
        num = settings.get("num_instances")
        if num is not None and (not _is_int(num) or num < 1):
            raise ConfigError(f"data.{name}_generate num_instances={num!r} must be an integer >= 1; set "
                              f"scale.{name}_instances")


def _check_model(cfg: DictConfig) -> None:
    from spade.models import presets

    role = _model_role(cfg)
    _check_number(cfg, "model.optimizer.lr", 0, low_open=True, fix=", e.g. 1e-3")
    _check_number(cfg, "model.optimizer.weight_decay", 0, none_ok=True)
    if role == "student":
        _check_choice(cfg, "model.size", presets("student"))
        _check_number(cfg, "model.bc_pos_weight", 0, low_open=True, none_ok=True, fix=" (null: plain BCE)")
        guidance = _get(cfg, "model.guidance")
        if guidance not in (_MISSING, None):
            _check_number(cfg, "model.guidance.weight", 0, fix=" (lambda; 0 turns the guidance off)")
            _check_choice(cfg, "model.guidance.clip", ["sample", "batch"])
            from spade.training.guidance import EXPERT_KINDS

            _check_choice(cfg, "model.guidance.expert", [k for k in EXPERT_KINDS if k], none_ok=True)
            _check_int(cfg, "model.guidance.num_noise", 1)
            _check_int(cfg, "model.guidance.t_min", 0)
            _check_int(cfg, "model.guidance.t_max", 1, none_ok=True)
    elif role == "expert":
        kind = "cond_expert" if _get(cfg, "model.conditional") is not False else "uncond_expert"
        _check_choice(cfg, "model.preset", presets(kind))
        _check_number(cfg, "model.ema_decay", 0, 1, high_open=True)
        _check_choice(cfg, "model.sampler", ["ddim", "ddpm"])
        _check_int(cfg, "model.num_inference_steps", 1)
        _check_int(cfg, "model.num_train_timesteps", 2)


def _check_checkpoints(cfg: DictConfig) -> None:
    role = _model_role(cfg)
    train_data = ("train_dir", "test_dir")
    ckpt = _get(cfg, "ckpt_path")
    if ckpt is not _MISSING and role is not None:
        fix = "pass checkpoints/last.ckpt of an interrupted run of this experiment (under its logs/runs/ folder)"
        info = _check_checkpoint("ckpt_path", ckpt, role, fix)
        _check_geometry("ckpt_path", ckpt, info, cfg, train_data)
    init = _get(cfg, "model.init_ckpt")
    if init is not _MISSING:
        info = _check_checkpoint("model.init_ckpt", init, "student",
                                 "pass a student checkpoint (the pretrained student of the fine-tuning row)")
        _check_geometry("model.init_ckpt", init, info, cfg, train_data)
    expert = _get(cfg, "model.guidance.expert_ckpt")
    if expert is not _MISSING:
        info = _check_checkpoint("model.guidance.expert_ckpt", expert, "expert",
                                 "pass an expert checkpoint (from an expert_* experiment), or leave it null so that "
                                 "the experiment's requires.expert finds or trains one")
        _check_geometry("model.guidance.expert_ckpt", expert, info, cfg, train_data)
        _check_expert_kind(cfg, expert, info)


def _check_expert_kind(cfg: DictConfig, expert: Any, info: dict[str, Any] | None) -> None:
    """DBC needs an unconditional expert, Cond-DBC a conditional one (``model.guidance.expert``)."""
    from spade.training.errors import ExpertMismatchError
    from spade.training.guidance import check_expert_kind

    net_role = ((info or {}).get("config") or {}).get("role")
    if net_role not in ("cond_expert", "uncond_expert"):
        return
    wanted = _get(cfg, "model.guidance.expert")
    try:
        check_expert_kind(None if wanted is _MISSING else wanted, net_role == "cond_expert",
                          f"model.guidance.expert_ckpt={expert}")
    except ExpertMismatchError as exc:
        raise ConfigError(str(exc)) from None


def validate_train_config(cfg: DictConfig) -> None:
    """Every check of ``spade.train``'s config that needs no training: raises :class:`ConfigError` (one line)."""
    _check_int(cfg, "seed", 0, 2**32 - 1, none_ok=True, fix=", e.g. seed=42")
    _check_choice(cfg, "prerequisites", ["train", "error"])
    for key in ("train", "test", "test_untrained"):
        value = _get(cfg, key)
        if value is not _MISSING and value is not None and not isinstance(value, bool):
            raise ConfigError(f"{key}={value!r} is not a boolean; set {key}=true or {key}=false")
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
    if not path.is_file():
        raise ConfigError(f"ckpt_path={ckpt} does not exist; {fix}")
    info = checkpoint_info(path)
    if info.get("role") not in ("student", "expert"):
        raise ConfigError(f"ckpt_path={ckpt} is not a SPADE student or expert checkpoint (role "
                          f"{info.get('role')!r}); {fix}")
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


# -- reporting ------------------------------------------------------------------------------------------------------
def user_errors() -> tuple[type[BaseException], ...]:
    """Exceptions that mean the user must change something (reported without a traceback)."""
    from spade.experiments.prerequisites import PrerequisiteMissing

    errors: list[type[BaseException]] = [ConfigError, DatasetError, PrerequisiteMissing]
    try:
        from spade.training.student_module import ExpertMismatchError

        errors.append(ExpertMismatchError)
    except ImportError:  # pragma: no cover - the module is always there
        pass
    try:
        from spade.annotation.pipeline import NotEnoughInstancesError

        errors.append(NotEnoughInstancesError)
    except ImportError:  # pragma: no cover
        pass
    return tuple(errors)


def exit_on_user_error(fn: Callable[..., Any]) -> Callable[..., Any]:
    """Wrap an entry point's task function: a user error ends the process with one line and exit status 2.

    ``HYDRA_FULL_ERROR=1`` re-raises it instead, for Hydra's full traceback.
    """

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return fn(*args, **kwargs)
        except user_errors() as exc:
            if os.environ.get("HYDRA_FULL_ERROR") == "1":
                raise
            print(f"error: {exc}", file=sys.stderr, flush=True)
            raise SystemExit(2) from None

    return wrapper
