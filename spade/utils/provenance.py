"""Where a result comes from: the command line, the code's commit, the machine (results pages state all three), and
:func:`shown_path`, the form in which a results page prints a path or a tracking URI (never the writing machine's
absolute path)."""

from __future__ import annotations

import datetime
import os
import platform
import shlex
import subprocess
import sys
from pathlib import Path

from spade.utils.timing import cpu_model

__all__ = ["command_line", "commit", "machine", "provenance_lines", "shown_path", "shown_roots"]

REPO_ROOT = Path(__file__).resolve().parents[2]
# URI prefixes whose rest is a filesystem path: what stays in front of the shown path ("file://" is dropped, since a
# relative path is a tracking URI MLflow reads as a local store, and "file:" URIs cannot be relative).
_PATH_URIS = {"sqlite:///": "sqlite:///", "file://": ""}


def shown_roots() -> list[Path]:
    """The folders a shown path is made relative to, the first that holds it winning: ``$SPADE_HOME`` (where data,
    logs and the MLflow store live when it is set), the repository root (a checkout's, not an installed package's
    site-packages), the current directory (SPADE's default home, ``conf/paths/default.yaml``)."""
    roots = [Path(os.environ["SPADE_HOME"])] if os.environ.get("SPADE_HOME") else []
    if (REPO_ROOT / "pyproject.toml").is_file():
        roots.append(REPO_ROOT)
    try:
        roots.append(Path.cwd())
    except FileNotFoundError:  # the current directory was removed
        pass
    return [Path(os.path.abspath(r.expanduser())) for r in roots]


def _relative(path: str) -> str | None:
    """``path`` relative to the first of :func:`shown_roots` that holds it; None when it is relative already or
    lies under none of them."""
    if not os.path.isabs(path):
        return None
    absolute = Path(os.path.abspath(path))
    for root in shown_roots():
        if absolute == root or root in absolute.parents:
            return absolute.relative_to(root).as_posix() or "."
    return None


def shown_path(path_or_uri: str | os.PathLike) -> str:
    """A path or tracking URI as a results page prints it: relative to the project, never the writing machine's
    absolute path.

    An absolute path under ``$SPADE_HOME``, the repository root or the current directory (:func:`shown_roots`)
    becomes relative to it: ``/work/main/logs/mlflow.db`` -> ``logs/mlflow.db``; so does the path of a
    ``sqlite:///ABS`` URI (``sqlite:////work/main/logs/mlflow.db`` -> ``sqlite:///logs/mlflow.db``, which MLflow
    reads relative to the directory it runs in) and of a ``file://ABS`` URI (shown as the bare relative path).
    Anything else (a relative path, a path elsewhere, an ``http://`` server, ``databricks``) is returned unchanged.
    Results pages (``spade.report``, ``spade.critic``, ``spade.perf.alternatives``...) pass every path and URI they
    print through it.
    """
    text = os.fspath(path_or_uri)
    for prefix, shown in _PATH_URIS.items():
        if text.startswith(prefix):
            rel = _relative(text[len(prefix):])
            return text if rel is None else shown + rel
    rel = _relative(text)
    return text if rel is None else rel


def _shown_argument(arg: str) -> str:
    """A command-line argument with its path shown by :func:`shown_path` (``key=PATH`` or a bare ``PATH``)."""
    key, sep, value = arg.partition("=")
    if sep and "/" not in key:
        return f"{key}={shown_path(value)}"
    return shown_path(arg)


def command_line(module: str) -> str:
    """``python -m <module>`` with this process's arguments, quoted as a shell would need them; absolute paths in
    them are shown as :func:`shown_path` shows them (the command as typed from the project's folder)."""
    return " ".join(["python", "-m", module, *(shlex.quote(_shown_argument(a)) for a in sys.argv[1:])])


def commit() -> str | None:
    """The checkout's commit (``+changes`` when tracked files differ from it); None outside a git checkout."""
    root = REPO_ROOT
    try:
        head = subprocess.run(["git", "-C", str(root), "rev-parse", "--short=12", "HEAD"], capture_output=True,
                              text=True, timeout=10, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return head + (" +changes" if dirty else "")


def machine() -> str:
    """Host, CPU model and count, operating system."""
    return f"{platform.node()}: {cpu_model()}, {os.cpu_count()} cores, {platform.system()} {platform.release()}"


def provenance_lines(command: str | None, launch: str | None = None) -> list[str]:
    """A results page's provenance block, as Markdown list items: the command that wrote it (with the one that
    launches its runs, when given), the code's commit, the date and the machine. A page adds its own items (its
    records, the wall time of its runs); the caller puts a blank line before the block (Markdown starts no list
    inside a paragraph)."""
    lines = [f"- command: `{command}`" + (f" (launch: `{launch}`)" if launch else "")] if command else []
    return [*lines, f"- commit: {commit() or 'unknown (not a git checkout)'}",
            f"- date: {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC", f"- machine: {machine()}"]
