"""What the MLflow UI tests share: ``mlflow server`` on a free local port in front of a temporary SPADE home's store,
and ``spade.train`` run into that home, told the server's address so that the URLs it prints point there.

:func:`served_home` is the fixture (``test_mlflow_ui.py``): it skips before any work
when there is no browser, creates the store before the server opens it and stops the server at the end.
"""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from browser_support import chromium_path

REPO = Path(__file__).resolve().parents[1]
# The smoke experiment, cut to a couple of batches per stage (its expert prerequisite inherits the trainer keys).
FAST = ["trainer.enable_progress_bar=false", "+trainer.limit_train_batches=2", "+trainer.limit_val_batches=1",
        "+trainer.limit_test_batches=1"]


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def wait_healthy(url: str, proc: subprocess.Popen, log: Path, timeout: float) -> None:
    deadline = time.time() + timeout
    while time.time() < deadline:
        if proc.poll() is not None:
            raise AssertionError(f"mlflow server exited ({proc.returncode}):\n{log.read_text()[-3000:]}")
        try:
            with urllib.request.urlopen(f"{url}/health", timeout=2) as response:
                if response.status == 200:
                    return
        except OSError:
            time.sleep(0.5)
    raise AssertionError(f"mlflow server not healthy after {timeout:.0f} s:\n{log.read_text()[-3000:]}")


def printed(out: str, label: str) -> str:
    """The URL ``spade.train`` printed after ``label:``."""
    match = re.search(rf"{label}:\s+(http://\S+)", out)
    assert match, f"the run printed no {label!r} URL:\n{out[-3000:]}"
    return match.group(1)


@contextmanager
def mlflow_server(store: str, port: int, workdir: Path) -> Iterator[subprocess.Popen]:
    """``mlflow server`` on 127.0.0.1:``port`` in front of ``store`` (one worker); stopped on exit."""
    log = workdir / "server.log"
    env = {k: v for k, v in os.environ.items() if k != "MLFLOW_TRACKING_URI"}
    with open(log, "w") as log_fh:
        server = subprocess.Popen(
            [sys.executable, "-m", "mlflow", "server", "--backend-store-uri", store, "--host", "127.0.0.1",
             "--port", str(port), "--workers", "1", "--default-artifact-root", str(workdir / "server-artifacts")],
            cwd=workdir, env=env, stdout=log_fh, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        yield server
    finally:
        os.killpg(server.pid, signal.SIGTERM)  # the server and its uvicorn worker (this test's own process group)
        try:
            server.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(server.pid, signal.SIGKILL)
            server.wait()


@dataclass
class ServedHome:
    """A temporary SPADE home whose store (``logs/mlflow.db``) an ``mlflow server`` serves at :attr:`base`."""

    home: Path
    base: str
    store: str
    client: Any  # an MlflowClient on the store
    server: subprocess.Popen

    def train(self, *overrides: str, timeout: float = 900) -> str:
        """``python -m spade.train`` with ``overrides`` into this home; its output (it must exit 0)."""
        env = {**os.environ, "SPADE_HOME": str(self.home), "PYTHONUNBUFFERED": "1", "SPADE_MLFLOW_UI_URL": self.base}
        env.pop("MLFLOW_TRACKING_URI", None)
        done = subprocess.run([sys.executable, "-m", "spade.train", *overrides], cwd=REPO, env=env,
                              capture_output=True, text=True, timeout=timeout)
        out = done.stdout + done.stderr
        assert done.returncode == 0, out[-3000:]
        return out

    def wait_healthy(self, timeout: float = 180) -> None:
        wait_healthy(self.base, self.server, self.home / "server.log", timeout=timeout)


@pytest.fixture
def served_home(tmp_path: Path) -> Iterator[ServedHome]:
    """A :class:`ServedHome` in ``tmp_path`` (skipped without a browser, before any work); the server boots while
    the test trains."""
    chromium_path()
    pytest.importorskip("playwright.sync_api")
    from mlflow import MlflowClient

    port = free_port()
    store = f"sqlite:///{tmp_path}/logs/mlflow.db"
    (tmp_path / "logs").mkdir()
    client = MlflowClient(tracking_uri=store)
    client.search_experiments()  # creates the store before the server and the run open it
    with mlflow_server(store, port, tmp_path) as server:
        yield ServedHome(tmp_path, f"http://127.0.0.1:{port}", store, client, server)
