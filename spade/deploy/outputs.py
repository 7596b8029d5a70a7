"""What SPADE's writers may replace: an existing output file only when SPADE wrote it and ``overwrite=true``.

One policy for the files a command writes, where the user points it or by default (``spade.plan out=``,
``spade.export out_path=`` (default: beside the checkpoint) and ``report_path=``, ``spade.report``'s pages in
``output_dir``, ``spade.bench``'s ``out_json``): a path that does not exist is written; an existing one is replaced
only with ``overwrite=true`` *and* when it is recognisably SPADE's (:func:`written_by_spade`: a PNG whose
``Software`` text chunk names SPADE, a model file carrying SPADE's ``spade`` entry, an export report, a report page
or CSV, a benchmark's JSON); anything else of the user's is never replaced, whatever the flag. Datasets follow the
same rule in :func:`spade.data.writer.check_output_dir`.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

from PIL import Image, PngImagePlugin

SOFTWARE = "SPADE"  # the PNG tEXt "Software" value of every picture SPADE writes (save_png, the report's chart)
REPORT_PROVENANCE = "- command: `python -m spade.report"  # the provenance line of every spade.report page
CRITIC_PROVENANCE = "- command: `python -m spade.critic"  # ... and of every spade.critic page
#: The header of each CSV file spade.report writes (spade.experiments.reporting.files, the closed-loop page):
#: its first fields, or (for <table>.csv, whose metric columns vary) fields it always holds.
REPORT_CSV_HEADS = (("kind", "comparison", "row", "baseline", "metric"), ("dataset", "condition", "row", "seeds"),
                    ("predictor", "reading", "markers", "seeds"))  # ... and the teacher page's
REPORT_CSV_FIELDS = frozenset({"table", "shape", "row", "status", "n_seeds", "seeds", "run_id", "n_runs"})
BENCH_KEYS = frozenset({"mode", "machine", "settings"})  # the top level of spade.bench's JSON (spade.perf.bench)
_HEAD_BYTES = 1 << 20  # how much of a text file is read to recognise it


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
            return isinstance(raw, dict) and ({"out_path", "format", "max_abs_diff"} <= set(raw)  # an ExportReport
                                              or BENCH_KEYS <= set(raw))
        if suffix == ".md":
            with p.open(encoding="utf-8") as fh:
                head = fh.read(_HEAD_BYTES)
                return f"\n{REPORT_PROVENANCE}" in head or f"\n{CRITIC_PROVENANCE}" in head
        if suffix == ".csv":
            with p.open(newline="", encoding="utf-8") as fh:
                header = next(csv.reader([fh.readline(_HEAD_BYTES)]), [])
            return any(tuple(header[:len(head)]) == head for head in REPORT_CSV_HEADS) or REPORT_CSV_FIELDS <= set(header)
    except Exception:  # noqa: BLE001 - unreadable, damaged or foreign: not SPADE's
        return False
    return False


def replace_refusal(key: str, path: str | Path, overwrite: bool, label: str | None = None) -> str | None:
    """Why the existing file at ``path`` (config ``key``) must not be replaced, or None when it may be written.
    ``label`` names the file in the message where ``key=path`` would not (a default path, a file in a folder)."""
    p = Path(path).expanduser()
    if not p.exists():
        return None
    name = label or f"{key}={path}"
    if not written_by_spade(p):
        return (f"{name} exists and was not written by SPADE: it is never replaced (not even with "
                f"overwrite=true); choose another {key}")
    if not overwrite:
        return f"{name} exists (written by SPADE earlier); pass overwrite=true to replace it, or choose another {key}"
    return None
