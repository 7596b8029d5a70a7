"""The MLflow store: created once, safely, and never by a reader.

- every path that may create the store takes the store's lock (``<store>.lock``): training's and evaluation's
  logger, the critic's (the same logger), ``spade.export register=`` and model URIs (the registry's client),
  ``spade.closed_loop``; an evaluation, a training and an ``export register=`` started together on a fresh store all
  succeed;
- a store creation interrupted (Ctrl+C) leaves no half-made store: the store is made in a temporary file beside
  it and moved into place once MLflow's schema is complete; a half-made store left by an older SPADE is refused,
  named, with the fix;
- a refusal leaves no FAILED run: a run refused before it recorded anything is deleted;
- a reader (``spade.report``, a model URI) never creates a store: a missing store, a file that is not an MLflow
  store and an unreachable tracking server are each one line, naming the store it looked in.
"""

from __future__ import annotations

import fcntl
import os
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest

from spade.config.preflight import validate_train_config
from spade.utils.errors import ConfigError

from factories import checkpoint, write_synthetic
from refusal_support import UNREACHABLE, one_error_line
from training_helpers import compose_row

REPO = Path(__file__).resolve().parents[1]


def runs_in(store: Path) -> list[tuple[str, str, str]]:
    """(name, status, lifecycle stage) of every run in the SQLite store ``store`` (none without a store)."""
    if not store.exists():
        return []
    db = sqlite3.connect(store)
    try:
        return [tuple(r) for r in db.execute("SELECT name, status, lifecycle_stage FROM runs")]
    finally:
        db.close()


def complete_store(uri: str) -> bool:
    """Whether the store at ``uri`` opens with MLflow and holds its Default experiment."""
    from mlflow import MlflowClient

    return MlflowClient(tracking_uri=uri).get_experiment("0") is not None


# -- 1. every path that creates a store takes its lock ----------------------------------------------------------------
_OPEN = r"""
import sys
uri, mode, cache = sys.argv[1], sys.argv[2], sys.argv[3]
import mlflow
from omegaconf import OmegaConf
from spade.deploy.mlflow_models import _mlflow
from spade.experiments.closed_loop_table import launch
from spade.tracking.logger import MLFlowLogger
print("ready", flush=True)
if mode == "logger":  # training, evaluation and the critic: SPADE's MLflow logger
    MLFlowLogger(experiment_name="race", tracking_uri=uri).experiment
elif mode == "registry":  # spade.export register=: the registry's client (a model URI never creates a store)
    _mlflow(uri).MlflowClient().search_registered_models()
elif mode == "closed_loop":
    launch(OmegaConf.create({"tracking_uri": uri, "cache_dir": cache, "sources": []}))
print("ok", flush=True)
"""
_MODES = ("logger", "registry", "closed_loop")


def _start(uri: str, mode: str, cache: Path) -> subprocess.Popen:
    """A process opening the store at ``uri`` by path ``mode``, started and its imports done (it said ``ready``)."""
    proc = subprocess.Popen([sys.executable, "-c", _OPEN, uri, mode, str(cache)], cwd=REPO, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert proc.stdout.readline().strip() == "ready", proc.stderr.read()[-2000:]
    return proc


def _open_by(mode: str, uri: str, cache: Path) -> None:
    """Open the store at ``uri`` as path ``mode`` of SPADE does (:data:`_OPEN`, in this process)."""
    from omegaconf import OmegaConf

    from spade.deploy.mlflow_models import _mlflow
    from spade.experiments.closed_loop_table import launch
    from spade.tracking.logger import MLFlowLogger

    if mode == "logger":
        MLFlowLogger(experiment_name="race", tracking_uri=uri).experiment  # noqa: B018 - opens the run
    elif mode == "registry":
        _mlflow(uri).MlflowClient().search_registered_models()
    else:
        assert launch(OmegaConf.create({"tracking_uri": uri, "cache_dir": str(cache), "sources": []})) == []


@pytest.mark.parametrize("mode", _MODES)
def test_every_path_that_creates_a_store_waits_for_its_lock(tmp_path: Path, mode: str) -> None:
    """An evaluation, a training and an ``export register=`` started together on a fresh store crashed
    (``table ... already exists``): the registry's client (and ``spade.closed_loop``'s) created the store without
    the lock. Held here (another open file of ``<store>.lock``: ``flock`` keeps it from this process's threads as
    from other processes), the lock keeps each path from creating the store until it is released."""
    import threading

    store = tmp_path / "logs" / "mlflow.db"
    uri = f"sqlite:///{store}"
    store.parent.mkdir(parents=True)
    errors: list[BaseException] = []

    def opening() -> None:
        try:
            _open_by(mode, uri, tmp_path / "cache")
        except BaseException as exc:  # noqa: BLE001 - reported by the test
            errors.append(exc)

    import spade.deploy.mlflow_models, spade.experiments.closed_loop_table, spade.tracking.logger  # noqa: F401, E401

    with open(store.with_name("mlflow.db.lock"), "a") as lock:  # imported first: the thread only opens the store
        fcntl.flock(lock, fcntl.LOCK_EX)
        worker = threading.Thread(target=opening, daemon=True)
        worker.start()
        worker.join(timeout=3)  # long enough to create the store, were the lock not taken
        assert worker.is_alive() and not store.exists(), errors
    worker.join(timeout=120)
    assert not worker.is_alive() and not errors, errors
    assert complete_store(uri)


@pytest.mark.slow  # three processes racing on fresh stores (a minute on two loaded cores)
def test_three_paths_create_one_fresh_store_together(tmp_path: Path) -> None:
    """A logger (training, evaluation), the registry's client (``export register=``) and
    ``spade.closed_loop`` open one fresh store at once, three times over: all three succeed, every time."""
    for attempt in range(3):
        uri = f"sqlite:///{tmp_path / f'store{attempt}' / 'mlflow.db'}"
        procs = [_start(uri, mode, tmp_path / "cache") for mode in _MODES]
        outs = [p.communicate(timeout=300) for p in procs]
        assert all(p.returncode == 0 for p in procs), [o[1][-2000:] for o in outs]
        assert complete_store(uri)


# -- 2. an interrupted creation leaves no half-made store ------------------------------------------------------------
def _interrupt_migrations(monkeypatch: pytest.MonkeyPatch) -> None:
    """Ctrl+C in the middle of MLflow's schema migrations (its initial tables made, the upgrade not)."""
    import mlflow.store.db.utils as db_utils

    def interrupted(engine) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(db_utils, "_upgrade_db", interrupted)


def test_an_interrupted_creation_leaves_no_store(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Ctrl+C while a fresh store was created left a half-made store on which every later command failed. The
    store is made in a temporary file moved into place once complete: interrupted, nothing is left (no store, no
    temporary file), and the next command creates a complete store."""
    from spade.tracking.client import ensure_store

    store = tmp_path / "logs" / "mlflow.db"
    uri = f"sqlite:///{store}"
    with monkeypatch.context() as patch:
        _interrupt_migrations(patch)
        with pytest.raises(KeyboardInterrupt):
            ensure_store(uri)
    assert sorted(p.name for p in store.parent.iterdir()) == ["mlflow.db.lock"]
    ensure_store(uri)
    assert complete_store(uri)
    assert sorted(p.name for p in store.parent.iterdir()) == ["mlflow.db", "mlflow.db.lock"]


def test_a_half_made_store_is_named_with_the_fix(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A half-made store an older SPADE left (its creation interrupted in place) is refused, in one line naming the
    file and the fix (delete it: it holds no run), by the store check before any work and by the store's opening;
    once deleted, the store is created whole."""
    from mlflow import MlflowClient

    from spade.config.store_checks import check_store_file
    from spade.tracking.client import ensure_store
    from spade.utils.errors import ConfigError

    store = tmp_path / "mlflow.db"
    uri = f"sqlite:///{store}"
    with monkeypatch.context() as patch:
        _interrupt_migrations(patch)
        with pytest.raises(KeyboardInterrupt):
            MlflowClient(tracking_uri=uri).search_experiments()  # what an older SPADE did, in place
    assert store.is_file()
    for check in (lambda: check_store_file("logger.mlflow.tracking_uri", uri), lambda: ensure_store(uri)):
        with pytest.raises(ConfigError) as info:
            check()
        message = str(info.value)
        assert "half-made MLflow store" in message and str(store) in message and f"rm {store}" in message
        assert "\n" not in message
    from spade.deploy.mlflow_store import _dispose

    _dispose(uri)  # this process's cached connection to the half-made file (a new command has none)
    store.unlink()
    ensure_store(uri)
    assert complete_store(uri)


# -- 3. a refusal leaves no FAILED run ----------------------------------------------------------------------------------
def test_a_refused_evaluation_leaves_no_run(tmp_path: Path, run_main) -> None:
    """An empty test set (no instance of ``data.test_shape``) was refused in one line but left a FAILED run: the
    refusal came after Lightning opened the run. A run refused before it recorded anything is deleted."""
    test = tmp_path / "test"
    write_synthetic(test, n=4)
    ckpt = checkpoint(tmp_path / "student.ckpt")
    code, err = run_main("spade.evaluate", [f"ckpt_path={ckpt}", "data=own", f"data.test_dir={test}",
                                            "data.test_shape=Z"])
    assert code == 2 and "holds no test instances of that shape" in one_error_line(err), err
    runs = runs_in(tmp_path / "home" / "logs" / "mlflow.db")
    assert runs and all(stage == "deleted" for _, _, stage in runs), runs


def test_report_refuses_a_store_that_does_not_exist(tmp_path: Path, run_main) -> None:
    """``tracking_uri=sqlite:///<missing dir>/mlflow.db`` created an empty store and reported all missing."""
    from spade.utils.config import compose_config
    from spade.experiments.reporting.pages import report

    store = tmp_path / "missing" / "mlflow.db"
    code, err = run_main("spade.report", [f"tracking_uri=sqlite:///{store}", f"output_dir={tmp_path / 'rep'}"])
    assert code == 2, err
    assert "no MLflow store" in one_error_line(err)
    cfg = compose_config("report", [f"tracking_uri=sqlite:///{store}", f"output_dir={tmp_path / 'rep'}",
                                    "paths.output_dir=."])
    with pytest.raises(ConfigError, match="no MLflow store"):
        report(cfg)
    assert not store.parent.exists() and not (tmp_path / "rep").exists()


@pytest.mark.parametrize("kind", ["foreign_sqlite", "garbage"])
def test_report_reads_without_writing_into_a_file_that_is_not_an_mlflow_store(tmp_path: Path, run_main,
                                                                              kind: str) -> None:
    """With SPADE_HOME holding someone else's SQLite file named ``mlflow.db``, ``spade.report`` created
    about 40 MLflow tables in it. A reader refuses it in one line, the file byte for byte unchanged."""
    import sqlite3

    store = tmp_path / "mlflow.db"
    if kind == "foreign_sqlite":
        db = sqlite3.connect(store)
        db.execute("CREATE TABLE notes (id INTEGER PRIMARY KEY, text TEXT)")
        db.execute("INSERT INTO notes (text) VALUES ('mine')")
        db.commit()
        db.close()
        expected = "is an SQLite database but not an MLflow store"
    else:
        store.write_bytes(b"not a database at all\n" * 100)
        expected = "is not an SQLite database"
    before = store.read_bytes()
    code, err = run_main("spade.report", [f"tracking_uri=sqlite:///{store}", f"output_dir={tmp_path / 'rep'}"])
    assert code == 2, err
    assert expected in one_error_line(err)
    assert store.read_bytes() == before and not (tmp_path / "rep").exists()
    # a run logging there is refused the same way, before any work
    with pytest.raises(ConfigError, match=expected):
        validate_train_config(compose_row("t1_small_bc_L", tmp_path, f"logger.mlflow.tracking_uri=sqlite:///{store}"))
    assert store.read_bytes() == before


def test_an_unreachable_tracking_server_fails_fast_in_one_line(run_main) -> None:
    """``spade.report tracking_uri=http://127.0.0.1:9/`` retried silently for 253 s, then a traceback."""
    start = time.monotonic()
    code, err = run_main("spade.report", ["table=table1", f"tracking_uri={UNREACHABLE}"])
    assert code == 2, err
    assert "no tracking server answers there" in one_error_line(err)
    assert time.monotonic() - start < 20


_RACE = """
import sys, time
uri, mode, start = sys.argv[1], sys.argv[2], float(sys.argv[3])
if mode == "spade":
    from spade.tracking.client import ensure_store as open_store
else:
    from mlflow import MlflowClient
    open_store = lambda uri: MlflowClient(tracking_uri=uri).search_experiments()
while time.time() < start:
    time.sleep(0.001)
open_store(uri)
print("ok")
"""


@pytest.mark.slow  # processes racing on a fresh store
def test_two_processes_create_a_fresh_store_safely(tmp_path: Path) -> None:
    """Two ``spade.train`` on a fresh store crashed one of them (``duplicate column name: outputs`` while
    MLflow created its tables). SPADE opens a fresh SQLite store under a file lock: both succeed, every time."""
    for attempt in range(3):
        uri = f"sqlite:///{tmp_path / f'store{attempt}' / 'mlflow.db'}"
        start = time.time() + 15  # both imported and waiting by then
        procs = [subprocess.Popen([sys.executable, "-c", _RACE, uri, "spade", str(start)], cwd=REPO,
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for _ in range(2)]
        outs = [p.communicate(timeout=300) for p in procs]
        assert all(p.returncode == 0 for p in procs), [o[1][-2000:] for o in outs]
        from mlflow import MlflowClient

        assert MlflowClient(tracking_uri=uri).search_experiments()  # the Default experiment: a complete store


def test_a_model_uri_names_the_store_it_looked_in_and_never_creates_one(tmp_path: Path) -> None:
    from spade.deploy.mlflow_models import RegistryError, resolve_model

    store = f"sqlite:///{tmp_path}/logs/mlflow.db"
    with pytest.raises(RegistryError) as missing:
        resolve_model("runs:/0123456789abcdef0123456789abcdef/model", store, tmp_path / "logs" / "registry-cache")
    message = str(missing.value)
    assert f"no MLflow store at {store}" in message and "none was created" in message
    assert "MLFLOW_TRACKING_URI" in message and "paths.mlflow_tracking_uri" in message
    assert not (tmp_path / "logs").exists()  # neither the store nor the cache folder

    from mlflow import MlflowClient

    MlflowClient(tracking_uri=store).search_experiments()  # an existing store, without that run
    with pytest.raises(RegistryError) as absent:
        resolve_model("runs:/0123456789abcdef0123456789abcdef/model", store)
    message = str(absent.value)
    assert f"cannot be fetched from the MLflow store at {store}" in message and "MLFLOW_TRACKING_URI" in message


@pytest.mark.timeout(300)
def test_plan_with_a_runs_uri_from_another_folder_creates_no_store(tmp_path: Path) -> None:
    env = {k: v for k, v in os.environ.items() if k not in ("MLFLOW_TRACKING_URI", "SPADE_HOME")}
    done = subprocess.run([sys.executable, "-m", "spade.plan", "warehouse:101", "start=3,4,0", "goal=6,6",
                           "model=runs:/0123456789abcdef0123456789abcdef/model"], cwd=tmp_path, env=env,
                          capture_output=True, text=True, timeout=240)
    assert done.returncode == 2, done.stdout + done.stderr
    assert f"no MLflow store at sqlite:///{tmp_path}/logs/mlflow.db" in done.stderr, done.stderr
    assert "MLFLOW_TRACKING_URI" in done.stderr
    assert not (tmp_path / "logs" / "mlflow.db").exists()
