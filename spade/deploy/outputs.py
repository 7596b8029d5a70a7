"""What SPADE's writers may replace: an existing output file only when SPADE wrote it and ``overwrite=true``.

One policy for the files a command writes where the user points it (``spade.plan out=``, ``spade.export out_path=``
and ``report_path=``): a path that does not exist is written; an existing one is replaced only with
``overwrite=true`` *and* when it is recognisably SPADE's (:func:`written_by_spade`: a PNG whose ``Software`` text
chunk names SPADE, a model file carrying SPADE's ``spade`` entry, an export report);
anything else of the user's is never replaced, whatever the flag. Datasets follow the same rule in
:func:`spade.data.writer.check_output_dir`.
"""

from __future__ import annotations

import json
from pathlib import Path

from PIL import Image, PngImagePlugin

SOFTWARE = "SPADE"  # the PNG tEXt "Software" value of every picture SPADE writes through save_png


def save_png(image: Image.Image, path: str | Path) -> Path:
    """Save ``image`` as a PNG marked as SPADE's (its ``Software`` text chunk), so that a later
    ``overwrite=true`` may replace it."""
    info = PngImagePlugin.PngInfo()
    info.add_text("Software", SOFTWARE)
    path = Path(path)
    image.save(path, format="PNG", pnginfo=info)
    return path


def written_by_spade(path: str | Path) -> bool:
    """Whether the file at ``path`` is recognisably SPADE's (see the module docstring); never raises."""
    p = Path(path)
    suffix = p.suffix.lower()
    try:
        if suffix == ".png":
            with Image.open(p) as im:
                return str(getattr(im, "text", {}).get("Software", "")).startswith(SOFTWARE)
        if suffix in (".onnx", ".pt", ".ckpt"):
            from spade.models.modelfile import read_info

            return bool(read_info(p, required=False).get("role"))
        if suffix == ".json":
            raw = json.loads(p.read_text())
            return isinstance(raw, dict) and {"out_path", "format", "max_abs_diff"} <= set(raw)  # an ExportReport
    except Exception:  # noqa: BLE001 - unreadable, damaged or foreign: not SPADE's
        return False
    return False


def replace_refusal(key: str, path: str | Path, overwrite: bool) -> str | None:
    """Why the existing file at ``path`` (config ``key``) must not be replaced, or None when it may be written."""
    p = Path(path).expanduser()
    if not p.exists():
        return None
    if not written_by_spade(p):
        return (f"{key}={path} exists and was not written by SPADE: it is never replaced (not even with "
                f"overwrite=true); choose another {key}")
    if not overwrite:
        return f"{key}={path} exists (written by SPADE earlier); pass overwrite=true to replace it, or choose another {key}"
    return None
