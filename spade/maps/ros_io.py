"""Read and write ROS map_server maps (a yaml file plus a pgm/png image) with Nav2 semantics.

Loading follows ``nav2_map_server/src/map_io.cpp`` (``loadMapFromFile`` in the current, Eigen-based version):

* the image path in the yaml is relative to the yaml's folder unless absolute;
* the image is turned to grey by GraphicsMagick's ``GrayscaleType`` conversion, i.e. Rec.601 luma
  (0.299 R + 0.587 G + 0.114 B) for colour images; Pillow's ``convert("L")`` uses the same weights;
* ``p = 1 - v / 255`` (``p = v / 255`` when ``negate`` is set), computed in float32 as Nav2 does;
* ``mode: trinary`` (default): occupied (100) if ``p >= occupied_thresh``, free (0) if ``p <= free_thresh``,
  unknown (-1) otherwise;
* ``mode: scale``: as trinary, but in-between values become ``round((p - free) / (occ - free) * 100)``;
* ``mode: raw``: the grey value itself when it lies in 0..100, unknown otherwise (no negate, no alpha);
* in trinary and scale modes, pixels whose alpha is below 255 are unknown.

Older Nav2 releases (the per-pixel Magick loop) averaged R, G, B (and alpha, in trinary mode) instead of taking
luma, and compared with strict inequalities; maps whose grey levels sit exactly on a threshold, or colour/RGBA
maps with translucent pixels, can differ between the two.

The three-level ``OccupancyMap.grid`` is derived from these ``nav_msgs/OccupancyGrid`` values as Nav2's costmap
``StaticLayer`` does with ``trinary_costmap: true`` and ``track_unknown_space: true``: -1 -> UNKNOWN,
value >= ``lethal_threshold`` (``lethal_cost_threshold``, default 100) -> OCCUPIED, any other value -> FREE.
For trinary maps this is exactly the trinary split; for scale and raw maps the 0..100 values are also kept in
``OccupancyMap.costs``.

Saving writes a trinary map as Nav2's map_saver does (254 free, 0 occupied, 205 unknown) with thresholds
0.65 / 0.196, so that ``load_ros_map(save_ros_map(m, path))`` reproduces ``m.grid`` exactly.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from PIL import Image, UnidentifiedImageError

from spade.maps.occupancy import FREE, OCCUPIED, UNKNOWN, OccupancyMap
from spade.utils.errors import UserError

MODES = ("trinary", "scale", "raw")

# map_saver's trinary grey levels and the thresholds written next to them.
SAVE_FREE_VALUE = 254
SAVE_OCCUPIED_VALUE = 0
SAVE_UNKNOWN_VALUE = 205
SAVE_OCCUPIED_THRESH = 0.65
SAVE_FREE_THRESH = 0.196


class MapFormatError(UserError, ValueError):
    """A ROS map yaml or its image cannot be read; the message names the file and the fix."""


@dataclass(frozen=True)
class MapMetadata:
    """The contents of a map_server yaml, validated."""

    yaml_path: Path
    image_path: Path
    resolution: float
    origin: tuple[float, float, float]
    negate: bool
    occupied_thresh: float
    free_thresh: float
    mode: str


# --------------------------------------------------------------------------------------------- yaml
def _fail(yaml_path: Path, problem: str, fix: str) -> MapFormatError:
    return MapFormatError(f"{yaml_path}: {problem}. Fix: {fix}")


def _require(doc: dict[str, Any], key: str, yaml_path: Path, example: str) -> Any:
    if key not in doc or doc[key] is None:
        raise _fail(yaml_path, f"the map yaml has no '{key}' key", f"add a line such as '{example}' (Nav2 requires it)")
    return doc[key]


def _number(value: Any, key: str, yaml_path: Path, example: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _fail(yaml_path, f"'{key}' must be a number, got {value!r}", f"write it as e.g. '{example}'")
    number = float(value)
    if not math.isfinite(number):
        raise _fail(yaml_path, f"'{key}' must be finite, got {value!r}", f"write it as e.g. '{example}'")
    return number


def read_map_yaml(yaml_path: str | Path) -> MapMetadata:
    """Parse and validate a map_server yaml (no image access besides checking that the file exists)."""
    path = Path(yaml_path)
    if not path.is_file():
        raise _fail(path, "the map yaml does not exist or is not a file", "pass the path of an existing map .yaml")
    try:
        doc = yaml.safe_load(path.read_text(encoding="utf-8"))
    except yaml.YAMLError as exc:
        raise _fail(path, f"malformed YAML ({exc})".replace("\n", " "), "correct the YAML syntax") from exc
    except (OSError, UnicodeDecodeError) as exc:
        raise _fail(path, f"cannot read the file ({exc})", "check that it is a readable UTF-8 text file") from exc
    if not isinstance(doc, dict):
        raise _fail(
            path,
            f"a map yaml must be a mapping of keys (image, resolution, origin, ...), got {type(doc).__name__}",
            "write 'key: value' lines as map_server expects",
        )

    image = _require(doc, "image", path, "image: map.pgm")
    if not isinstance(image, str) or not image.strip():
        raise _fail(path, f"'image' must be a non-empty file name, got {image!r}", "set 'image: <file>.pgm'")
    image_path = Path(image)
    if not image_path.is_absolute():
        image_path = path.parent / image_path

    resolution = _number(_require(doc, "resolution", path, "resolution: 0.05"), "resolution", path, "0.05")
    if resolution <= 0.0:
        raise _fail(path, f"'resolution' must be > 0 metres per pixel, got {resolution}", "set e.g. 'resolution: 0.05'")

    origin_raw = _require(doc, "origin", path, "origin: [0.0, 0.0, 0.0]")
    if not isinstance(origin_raw, (list, tuple)) or len(origin_raw) != 3:
        problem = f"'origin' must be a list of 3 numbers [x, y, yaw], got {origin_raw!r}"
        raise _fail(path, problem, "write 'origin: [x, y, yaw]'")
    origin = tuple(_number(v, "origin", path, "origin: [0.0, 0.0, 0.0]") for v in origin_raw)

    negate_raw = _require(doc, "negate", path, "negate: 0")
    if isinstance(negate_raw, bool):
        negate = negate_raw
    elif isinstance(negate_raw, int):
        negate = negate_raw != 0
    else:
        problem = f"'negate' must be 0 or 1, got {negate_raw!r}"
        raise _fail(path, problem, "write 'negate: 0' (or 1 to swap black/white)")

    occ = _number(_require(doc, "occupied_thresh", path, "occupied_thresh: 0.65"), "occupied_thresh", path, "0.65")
    free = _number(_require(doc, "free_thresh", path, "free_thresh: 0.196"), "free_thresh", path, "0.196")
    for key, value in (("occupied_thresh", occ), ("free_thresh", free)):
        if not 0.0 <= value <= 1.0:
            raise _fail(path, f"'{key}' must lie in [0, 1], got {value}", "use probabilities such as 0.65 / 0.196")
    if free >= occ:
        raise _fail(
            path,
            f"free_thresh ({free}) must be smaller than occupied_thresh ({occ})",
            "use e.g. occupied_thresh: 0.65 and free_thresh: 0.196",
        )

    mode = doc.get("mode", "trinary")
    if mode is None:
        mode = "trinary"
    if mode not in MODES:
        fix = f"set 'mode:' to one of {', '.join(MODES)} (or drop it for trinary)"
        raise _fail(path, f"unknown map mode {mode!r}", fix)

    return MapMetadata(
        yaml_path=path,
        image_path=image_path,
        resolution=resolution,
        origin=origin,  # type: ignore[arg-type]
        negate=negate,
        occupied_thresh=occ,
        free_thresh=free,
        mode=mode,
    )


# --------------------------------------------------------------------------------------------- image
def image_grey_alpha(img: Image.Image) -> tuple[np.ndarray, np.ndarray | None]:
    """Grey level (uint8, luma for colour) and alpha (uint8, or None when the image has none) of a PIL image."""
    mode = img.mode
    if mode in ("I;16", "I;16B", "I;16L", "I"):
        # 16-bit grey: GraphicsMagick scales 0..65535 to 0..255 when writing 8-bit channels.
        values = np.asarray(img, dtype=np.float64)
        return np.clip(np.rint(values / 257.0), 0, 255).astype(np.uint8), None
    if mode == "F":
        raise ValueError("floating-point images are not map images; save the map as 8-bit grey pgm/png")
    if mode in ("P", "PA"):
        has_alpha = mode == "PA" or "transparency" in img.info
        img = img.convert("RGBA" if has_alpha else "RGB")
        mode = img.mode
    if mode in ("LA", "La"):
        img = img.convert("LA")
        arr = np.asarray(img)
        return np.ascontiguousarray(arr[..., 0]), np.ascontiguousarray(arr[..., 1])
    if mode in ("RGBA", "RGBa"):
        img = img.convert("RGBA")
        alpha = np.asarray(img.getchannel("A"))
        grey = np.asarray(img.convert("RGB").convert("L"))
        return grey, alpha
    if mode == "L":
        return np.asarray(img), None
    return np.asarray(img.convert("RGB").convert("L")), None


def occupancy_values(
    grey: np.ndarray,
    alpha: np.ndarray | None,
    *,
    mode: str = "trinary",
    negate: bool = False,
    occupied_thresh: float = 0.65,
    free_thresh: float = 0.196,
) -> np.ndarray:
    """``nav_msgs/OccupancyGrid`` values (int8: -1 unknown, 0..100) of a grey image, as Nav2's map_io computes them.

    Rows stay in image order (row 0 = top); Nav2 flips them only when filling the message.
    """
    if mode not in MODES:
        raise ValueError(f"unknown map mode {mode!r}; use one of {MODES}")
    grey = np.asarray(grey, dtype=np.uint8)
    if mode == "raw":
        values = grey.astype(np.int16)
        return np.where(values <= 100, values, -1).astype(np.int8)
    shade = grey.astype(np.float32) / np.float32(255.0)
    p = (shade if negate else np.float32(1.0) - shade).astype(np.float64)
    out = np.full(grey.shape, -1, dtype=np.int8)
    out[p >= occupied_thresh] = 100
    out[p <= free_thresh] = 0
    if mode == "scale":
        between = (p > free_thresh) & (p < occupied_thresh)
        scaled = np.floor((p - free_thresh) / (occupied_thresh - free_thresh) * 100.0 + 0.5)
        out[between] = scaled[between].astype(np.int8)
    if alpha is not None:
        out[np.asarray(alpha) < 255] = -1
    return out


def codes_from_values(values: np.ndarray, lethal_threshold: int = 100) -> np.ndarray:
    """Three-level codes from OccupancyGrid values (Nav2 StaticLayer, trinary_costmap, track_unknown_space)."""
    values = np.asarray(values)
    codes = np.full(values.shape, FREE, dtype=np.uint8)
    codes[values >= lethal_threshold] = OCCUPIED
    codes[values < 0] = UNKNOWN
    return codes


def load_ros_map(yaml_path: str | Path, *, lethal_threshold: int = 100) -> OccupancyMap:
    """Load a map_server yaml + image as an ``OccupancyMap`` (Nav2 semantics; see the module docstring).

    ``lethal_threshold`` (1..100) only matters for ``mode: scale`` / ``mode: raw`` maps: values at or above it are
    OCCUPIED, lower ones FREE; their 0..100 values are kept in ``OccupancyMap.costs``.
    """
    if isinstance(lethal_threshold, bool) or not isinstance(lethal_threshold, int) or not 1 <= lethal_threshold <= 100:
        raise ValueError(f"lethal_threshold must be an int in 1..100 (Nav2 default 100), got {lethal_threshold!r}")
    meta = read_map_yaml(yaml_path)
    if not meta.image_path.is_file():
        raise _fail(
            meta.yaml_path,
            f"the image {meta.image_path} named by 'image:' does not exist",
            "put the image next to the yaml or correct the 'image:' entry (relative paths start at the yaml's folder)",
        )
    try:
        with Image.open(meta.image_path) as img:
            img.load()
            grey, alpha = image_grey_alpha(img)
    except (UnidentifiedImageError, OSError, ValueError) as exc:
        raise _fail(
            meta.yaml_path,
            f"cannot read the image {meta.image_path} ({exc})",
            "replace it with a valid 8-bit pgm or png map image",
        ) from exc
    values = occupancy_values(
        grey,
        alpha,
        mode=meta.mode,
        negate=meta.negate,
        occupied_thresh=meta.occupied_thresh,
        free_thresh=meta.free_thresh,
    )
    return OccupancyMap(
        grid=codes_from_values(values, lethal_threshold),
        resolution=meta.resolution,
        origin=meta.origin,
        name=meta.yaml_path.stem,
        costs=values if meta.mode != "trinary" else None,
    )


# --------------------------------------------------------------------------------------------- save
def _yaml_float(value: float) -> str:
    """Shortest round-trip float text that YAML 1.1 (PyYAML, yaml-cpp) reads back as the same float."""
    text = repr(float(value))
    if "e" in text and "." not in text.split("e")[0]:
        mantissa, exponent = text.split("e")
        text = f"{mantissa}.0e{exponent}"
    return text


def _yaml_str(text: str) -> str:
    """A file name as a YAML scalar: plain when safe, else double-quoted (JSON strings are valid YAML)."""
    return text if re.fullmatch(r"[A-Za-z0-9_][A-Za-z0-9_.\-]*", text) else json.dumps(text)


def save_ros_map(m: OccupancyMap, yaml_path: str | Path, *, image_format: str = "pgm") -> Path:
    """Write ``m`` as a trinary map_server map: ``<yaml stem>.<image_format>`` beside ``yaml_path`` plus the yaml.

    Grey levels as Nav2's map_saver writes them: free 254, occupied 0, unknown 205; thresholds 0.65 / 0.196.
    ``costs`` are not written. Returns the yaml path.
    """
    if image_format not in ("pgm", "png"):
        raise ValueError(f"image_format must be 'pgm' or 'png', got {image_format!r}")
    path = Path(yaml_path)
    if path.suffix not in (".yaml", ".yml"):
        raise ValueError(f"save_ros_map writes a .yaml file; got {path} (add the .yaml suffix)")
    path.parent.mkdir(parents=True, exist_ok=True)
    image_path = path.with_suffix(f".{image_format}")
    lut = np.empty(3, dtype=np.uint8)
    lut[FREE], lut[OCCUPIED], lut[UNKNOWN] = SAVE_FREE_VALUE, SAVE_OCCUPIED_VALUE, SAVE_UNKNOWN_VALUE
    Image.fromarray(np.ascontiguousarray(lut[m.grid])).save(image_path)
    ox, oy, oyaw = (_yaml_float(v) for v in m.origin)
    path.write_text(
        f"image: {_yaml_str(image_path.name)}\n"
        "mode: trinary\n"
        f"resolution: {_yaml_float(m.resolution)}\n"
        f"origin: [{ox}, {oy}, {oyaw}]\n"
        "negate: 0\n"
        f"occupied_thresh: {SAVE_OCCUPIED_THRESH}\n"
        f"free_thresh: {SAVE_FREE_THRESH}\n",
        encoding="utf-8",
    )
    return path
