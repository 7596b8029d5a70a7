"""A dataset's fingerprint: the one hash of what shaped a dataset, and the annotation settings that count.

:func:`fingerprint` is the only hash behind a data fingerprint anywhere in SPADE: a dataset's digest
(:func:`dataset_fingerprint`, the MLflow dataset input's digest), the hash of the settings that shape a dataset's
bytes (:func:`settings_fingerprint`, what ``spade.train`` checks an existing dataset against) and the data part of
a registered model's name (``spade.tracking.registry.data_fingerprint``).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

from spade.data.format import read_manifest_json

# Annotation settings that never change a dataset's bytes (where it goes, how fast it is made, what else is drawn).
# ``alternatives`` adds a file beside the instances and changes none of them: a test set made without them is still
# the test set (its run leaves the metrics that need them out, and says so).
NON_SHAPING_KEYS = frozenset({"out_dir", "overwrite", "workers", "states_per_task", "start_method", "progress", "preview",
                              "hydra", "alternatives"})


def fingerprint(value: Any, length: int = 10) -> str:
    """The first ``length`` hex digits of the sha256 of ``value`` as canonical JSON (sorted keys, other values as
    ``str``)."""
    blob = json.dumps(value, sort_keys=True, default=str).encode()
    return hashlib.sha256(blob).hexdigest()[:length]


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
    return fingerprint(shaping_settings(settings))


def dataset_fingerprint(root: str | Path) -> str:
    """A dataset's fingerprint: the manifest's own ``fingerprint`` when it records one; else the hash of the
    generator settings that shaped its bytes (:func:`settings_fingerprint`); else, for a manifest without them, a
    digest of its geometry and of every array file's sha256. Raises what
    :func:`spade.data.format.read_manifest_json` raises (a ``FileNotFoundError`` without a manifest)."""
    raw = read_manifest_json(root)
    stated = raw.get("fingerprint") or (raw.get("extra") or {}).get("fingerprint")
    if stated:
        return str(stated)[:36]  # MLflow's digest column holds 36 characters
    generator = raw.get("generator")
    if isinstance(generator, dict) and generator:
        return settings_fingerprint(generator)
    files = raw.get("files") or {}
    content = {
        "image_size": raw.get("image_size"), "resolution": raw.get("resolution"),
        "num_instances": raw.get("num_instances"), "frame": raw.get("frame"),
        "files": {k: (v or {}).get("sha256") for k, v in sorted(files.items()) if isinstance(v, dict)},
    }
    return fingerprint(content, 12)
