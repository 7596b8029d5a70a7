"""sha256 of a file, read in chunks: the dataset checks and the shipped models' pins use the same one."""

from __future__ import annotations

import hashlib
from pathlib import Path

_HASH_CHUNK = 1 << 22


def file_sha256(path: str | Path) -> str:
    """sha256 of a file, read in chunks (the file is never held in memory whole)."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        while chunk := handle.read(_HASH_CHUNK):
            digest.update(chunk)
    return digest.hexdigest()
