"""sha256 of a file, read in chunks: the dataset checks and the shipped models' pins use the same one."""

from __future__ import annotations

import hashlib
import os
import threading
from pathlib import Path

_HASH_CHUNK = 1 << 22
# (real path, device, inode, size, mtime_ns) -> sha256: a file hashed once in a process is not read again while it
# is unchanged (the config checks open a dataset before a run, the data module opens it again in the run)
_CACHE: dict[tuple[str, int, int, int, int], str] = {}
_CACHE_LOCK = threading.Lock()
_CACHE_MAX = 4096


def _identity(path: str | Path) -> tuple[str, int, int, int, int] | None:
    try:
        st = os.stat(path)
        return (os.path.realpath(path), st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns)
    except OSError:
        return None


def file_sha256(path: str | Path) -> str:
    """sha256 of a file, read in chunks (the file is never held in memory whole); remembered for the file as it is
    (same inode, size and modification time), so an unchanged file is hashed once per process."""
    before = _identity(path)
    if before is not None:
        with _CACHE_LOCK:
            known = _CACHE.get(before)
        if known is not None:
            return known
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        while chunk := handle.read(_HASH_CHUNK):
            digest.update(chunk)
    value = digest.hexdigest()
    if before is not None and _identity(path) == before:  # unchanged while it was read: safe to remember
        with _CACHE_LOCK:
            if len(_CACHE) >= _CACHE_MAX:
                _CACHE.clear()
            _CACHE[before] = value
    return value
