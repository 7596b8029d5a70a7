"""Where a result comes from: the command line, the code's commit, the machine (results pages state all three)."""

from __future__ import annotations

import os
import platform
import shlex
import subprocess
import sys
from pathlib import Path

from spade.utils.timing import cpu_model

__all__ = ["command_line", "commit", "machine"]


def command_line(module: str) -> str:
    """``python -m <module>`` with this process's arguments, quoted as a shell would need them."""
    return " ".join(["python", "-m", module, *(shlex.quote(a) for a in sys.argv[1:])])


def commit() -> str | None:
    """The checkout's commit (``+changes`` when tracked files differ from it); None outside a git checkout."""
    root = Path(__file__).resolve().parents[2]
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
