"""Checks of the window a dataset is cut with: large enough for the shortest manoeuvre its templates draw, the
size and resolution ``scale`` names, and a side the configured U-Net can halve."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from spade.training.module_options import StudentOptions
from spade.utils.errors import ConfigError
from spade.utils.option_checks import is_int, is_number

if TYPE_CHECKING:
    from spade.config.dataset_checks import ScaleOptions
    from spade.config.options import ModelOptions


def range_low(value: Any) -> float:
    """The smallest value of a template range: ``[a, b]``, a number, or a dict of ranges."""
    if isinstance(value, Mapping):
        return min(range_low(v) for v in value.values())
    if isinstance(value, (list, tuple)):
        return float(min(value))
    return float(value)


def check_window_holds_manoeuvre(settings: Mapping[str, Any], key: str) -> None:
    """Refuse a window too small for the shortest manoeuvre its templates can draw (plus the margins)."""
    window = settings.get("window") or {}
    size, res = window.get("size_px"), window.get("resolution_m")
    wkey = f"{key}.window.size_px" if key else "window.size_px"
    if not is_int(size) or size < 8:
        raise ConfigError(f"{wkey}={size!r} is not a window size; set it to an integer >= 8 pixels (the tiny scale "
                          "uses 64, the paper 128)")
    if not is_number(res) or res <= 0:
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
        need = range_low(tpl["leg_m"]) + range_low(tpl["radius_m"])  # the shortest leg and its turn, end to end
        have = size * res - 2 * margin
        if have < need:
            px = max(8, math.ceil((need + 2 * margin) / res - 1e-9))
            raise ConfigError(
                f"{wkey}={size} is too small for a {shape} manoeuvre: {size} px x {res:g} m/px leaves {have:.2f} m "
                f"inside the {margin:g} m margins, the shortest {shape} (leg + turn radius) needs {need:.2f} m; use "
                f"{wkey} >= {px} (or a coarser window.resolution_m)"
            )


def model_downsampling(model: ModelOptions | None) -> tuple[int, str] | None:
    """(the multiple every window side must be of, what says so) for the configured network, from its preset."""
    if model is None:
        return None
    from spade.models.cond_expert import COND_EXPERT_PRESETS  # heavy: diffusers
    from spade.models.student import STUDENT_PRESETS
    from spade.models.uncond_expert import UNCOND_EXPERT_PRESETS

    if isinstance(model, StudentOptions):
        widths = STUDENT_PRESETS.get(model.size)
        what = f"model.size={model.size}"
    else:
        presets = COND_EXPERT_PRESETS if model.conditional is not False else UNCOND_EXPERT_PRESETS
        widths = (presets.get(model.preset) or {}).get("widths")
        what = f"model.preset={model.preset}"
    if not widths:
        return None
    return 2 ** (len(widths) - 1), what


def check_window_size(scale: ScaleOptions, model: ModelOptions | None, settings: Mapping[str, Any],
                      key: str) -> None:
    """The data's window, ``scale.image_size`` and the U-Net's downsampling agree, before any data or prerequisite
    is made: ``scale.image_size`` alone does not resize the data, and a side the U-Net cannot halve fails only in
    the first forward pass."""
    window = settings.get("window") or {}
    size, res = window.get("size_px"), window.get("resolution_m")
    wkey = f"{key}.window.size_px"
    image_size = scale.image_size
    if is_int(image_size) and is_int(size) and image_size != size:
        raise ConfigError(
            f"scale.image_size={image_size} differs from {wkey}={size}, the window the data are cut with (the "
            f"data would stay {size} px); set both: scale.image_size={image_size} {wkey}={image_size}"
        )
    scale_res = scale.resolution_m
    if is_number(scale_res) and is_number(res) and not math.isclose(scale_res, res, rel_tol=1e-9):
        raise ConfigError(
            f"scale.resolution_m={scale_res:g} differs from {key}.window.resolution_m={res:g}, the data's metres per "
            f"pixel; set both: scale.resolution_m={scale_res:g} {key}.window.resolution_m={scale_res:g}"
        )
    found = model_downsampling(model)
    if found and is_int(size) and size % found[0]:
        multiple, what = found
        lower, upper = size // multiple * multiple, (size // multiple + 1) * multiple
        raise ConfigError(
            f"{wkey}={size} is not a multiple of {multiple}, which the U-Net of {what} needs ({multiple} = 2^its "
            f"downsamplings); use a window of {lower or upper} or {upper} px (and scale.image_size to match)"
        )
