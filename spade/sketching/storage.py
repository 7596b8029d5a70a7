"""The sketch file behind the app: saved sketches in the format ``python -m spade.annotate sketches=`` reads.

The file (see :mod:`spade.annotation.sketch_file`) is the only state: it is re-read on every request, so a
restarted server shows exactly what was saved. Every change is a read-modify-write under a lock (a
``threading.Lock`` for the requests of one server plus an ``fcntl`` lock on ``<file>.lock`` for several
servers or scripts on one file) and lands with one atomic ``os.replace`` of a fully written, fsynced
temporary file, so two saves racing both land and a crash never leaves a half-written file.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import re
import stat
import tempfile
import threading
from collections.abc import Iterator
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import yaml

from spade.annotation.sketch_file import load_sketch_file
from spade.utils.errors import UserError

NAME_PATTERN = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")


def _file_mode(path: Path) -> int:
    """The permission bits a rewrite of ``path`` keeps: the existing file's own (a save used to leave every
    ``sketches.yaml`` at 0600, mkstemp's mode), or for a new file what ``open`` gives one (0666 less the umask)."""
    try:
        return stat.S_IMODE(path.stat().st_mode)
    except FileNotFoundError:
        umask = os.umask(0o022)  # read it (Python has no getter) and put it back at once
        os.umask(umask)
        return 0o666 & ~umask


class StorageError(UserError, ValueError):
    """A change the sketch file refuses (unknown name, name taken, file of another map, a file that is no sketch
    file); ``status`` is the HTTP status the API answers with. At start-up it is a user error: one line, exit 2."""

    def __init__(self, message: str, status: int = 400) -> None:
        super().__init__(message)
        self.status = status


class SketchStore:
    """Saved sketches of one map in one sketch file.

    ``map_ref`` is what the file's ``map:`` key holds: the absolute path of a ROS map yaml or a generator spec
    such as ``warehouse:1``. An existing file must name the same map.
    """

    def __init__(self, path: str | Path, map_ref: str, build_command: str | None = None) -> None:
        self.path = Path(path).expanduser().resolve()
        self.map_ref = str(map_ref)
        self.build_command = build_command or f"python -m spade.annotate sketches={self.path}"
        self._lock = threading.Lock()
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if self.path.exists():
            doc = self._read()  # refuses a file of another map (one sketch file, one map)
            if doc["scenarios"]:
                try:
                    load_sketch_file(self.path)  # a hand-edited file must still be one spade.annotate reads
                except Exception as exc:  # noqa: BLE001 - SketchFileError and what a parser says of a bad file
                    raise StorageError(f"sketch file {self.path} cannot be read by spade.annotate ({exc}); fix it, "
                                       "move it away or pass another out_dir=", status=409) from None

    # -- reading ---------------------------------------------------------------------------------------------
    def _read(self) -> dict[str, Any]:
        """The file as it is now, checked on every request: a sketch file (readable YAML with ``map`` and a list
        of ``scenarios``) of this server's map. A file another server (of another map) or an edit of its ``map:``
        changed while this one runs is refused (409), never written into: one sketch file, one map."""
        if not self.path.exists():
            return {"map": self.map_ref, "scenarios": []}
        try:
            doc = yaml.safe_load(self.path.read_text()) or {}
        except (yaml.YAMLError, UnicodeDecodeError, OSError) as exc:
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise StorageError(f"sketch file {self.path} is not readable YAML ({first}); fix it or move it away (or "
                               "pick another out_dir=): nothing is saved into it meanwhile", status=409) from None
        if not isinstance(doc, dict) or "map" not in doc:
            raise StorageError(f"{self.path} is not a sketch file (no 'map' key); move it away or pick another "
                               "out_dir=", status=409)
        scenarios = doc.get("scenarios") or []
        if not isinstance(scenarios, list) or not all(isinstance(e, dict) for e in scenarios):
            raise StorageError(f"{self.path}: 'scenarios' is not a list of sketches; fix it or move it away",
                               status=409)
        recorded = str(doc["map"])
        if recorded != self.map_ref and _resolved(recorded, self.path) != self.map_ref:
            raise StorageError(f"sketch file {self.path} holds sketches of map {recorded!r}, not {self.map_ref!r} "
                               "(this server's map); one sketch file holds one map: pass another out_dir= (a second "
                               "server on this folder, or an edit of the file's map:, changed it)", status=409)
        return {"map": recorded, "scenarios": scenarios}

    def list(self) -> list[dict[str, Any]]:
        """Every saved sketch, in file order: ``name``, ``shape``, ``waypoints`` and the stats saved with it."""
        return list(self._read()["scenarios"])

    def get(self, name: str) -> dict[str, Any]:
        for entry in self.list():
            if entry.get("name") == name:
                return entry
        raise StorageError(f"no saved sketch named {name!r}", status=404)

    # -- changes ---------------------------------------------------------------------------------------------
    @contextlib.contextmanager
    def _locked(self) -> Iterator[dict[str, Any]]:
        """The current document, re-read under both locks; written back atomically when the block succeeds."""
        with self._lock, open(self.path.with_name(self.path.name + ".lock"), "a") as lock_file:
            fcntl.flock(lock_file, fcntl.LOCK_EX)
            try:
                doc = self._read()
                yield doc
                self._write(doc)
            finally:
                fcntl.flock(lock_file, fcntl.LOCK_UN)

    def _write(self, doc: dict[str, Any]) -> None:
        text = f"# Sketches saved by python -m spade.sketch; build a dataset with\n#   {self.build_command}\n"
        text += yaml.safe_dump({"map": doc["map"], "scenarios": doc["scenarios"]}, sort_keys=False,
                               default_flow_style=None, width=200)
        mode = _file_mode(self.path)
        fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", suffix=".tmp", dir=self.path.parent)
        try:
            with os.fdopen(fd, "w") as f:
                f.write(text)
                f.flush()
                os.fchmod(f.fileno(), mode)  # mkstemp's 0600 would replace the file's own mode on every save
                os.fsync(f.fileno())
            os.replace(tmp, self.path)
        except BaseException:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
            raise
        dir_fd = os.open(self.path.parent, os.O_RDONLY)
        try:
            os.fsync(dir_fd)
        finally:
            os.close(dir_fd)

    def append(self, shape: str, waypoints: list[list[float]], name: str | None = None,
               stats: dict[str, Any] | None = None) -> dict[str, Any]:
        """Append one sketch; ``name`` defaults to the first free ``{shape}{k:03d}``. Returns the saved entry."""
        if name is not None and not NAME_PATTERN.match(name):
            raise StorageError(f"sketch name {name!r} is not allowed: use 1-64 letters, digits, '_', '-' or '.', "
                               "starting with a letter or digit", status=422)
        with self._locked() as doc:
            taken = {str(e.get("name")) for e in doc["scenarios"]}
            if name is None:
                k = sum(1 for e in doc["scenarios"] if e.get("shape") == shape)
                while f"{shape}{k:03d}" in taken:
                    k += 1
                name = f"{shape}{k:03d}"
            elif name in taken:
                raise StorageError(f"a sketch named {name!r} is already saved; pick another name or delete it first",
                                   status=409)
            entry: dict[str, Any] = {
                "name": name,
                "shape": shape,
                "waypoints": [[round(float(x), 4), round(float(y), 4)] for x, y in waypoints],
                "saved": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            }
            if stats:
                entry["executed"] = stats
            doc["scenarios"].append(entry)
        return entry

    def delete(self, name: str) -> dict[str, Any]:
        """Remove the sketch ``name``; returns it (404 when there is none)."""
        with self._locked() as doc:
            for i, entry in enumerate(doc["scenarios"]):
                if entry.get("name") == name:
                    return doc["scenarios"].pop(i)
            raise StorageError(f"no saved sketch named {name!r}", status=404)


def _resolved(map_ref: str, sketch_file: Path) -> str:
    """A relative map path of a sketch file, as :func:`load_sketch_file` resolves it."""
    path = Path(map_ref).expanduser()
    if path.is_absolute() or ":" in map_ref:
        return map_ref
    return str((sketch_file.parent / path).resolve())
