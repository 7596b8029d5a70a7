"""The commands as processes (slow: each test starts processes, most of them train): a run killed
with ``kill -9`` and resumed tests the same best checkpoint, with the same numbers, as the uninterrupted run;
annotation workers end with their parent; the command lines fail in one line with exit status 2."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import hydra
import lightning as L
import pytest

from training_helpers import compose_row
from spade.tracking.predictors import TOP_LEVEL_FILTER

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parents[1]
TESTS = Path(__file__).resolve().parent
ROW = "t1_small_bc_L"
QUICK = ["trainer.enable_progress_bar=false", "model.grid_size=0", "callbacks.model_info.latency_runs=0",
         "model.val_metric_batches=0", "optimized_metric=val/loss_bc", "+trainer.num_sanity_val_steps=0",
         "data.batch_size=4", "data.eval_batch_size=8", "metrics.fid_extractor=randconv"]


class KillAtBatch(L.Callback):
    """``kill -9`` of its own process when training reaches batch ``batch`` of epoch ``epoch``: an interruption at
    a known place, with no sleeps and no polling
    (``+callbacks.kill._target_=test_command_processes.KillAtBatch``)."""

    def __init__(self, epoch: int, batch: int) -> None:
        self.epoch, self.batch = int(epoch), int(batch)

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx: int) -> None:
        if trainer.current_epoch == self.epoch and batch_idx == self.batch:
            os.kill(os.getpid(), signal.SIGKILL)


def _env(home: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in ("MLFLOW_TRACKING_URI", "HYDRA_FULL_ERROR")}
    return {**env, "SPADE_HOME": str(home), "PYTHONUNBUFFERED": "1", "OMP_NUM_THREADS": "1",
            "PYTHONPATH": os.pathsep.join([str(TESTS), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)}


def _run(args: list[str], home: Path, timeout: float = 600) -> tuple[int, str]:
    home.mkdir(parents=True, exist_ok=True)
    out = home / f"output-{time.monotonic_ns()}.txt"
    with open(out, "w") as sink:
        proc = subprocess.run([sys.executable, *args], cwd=REPO, env=_env(home), stdout=sink,
                              stderr=subprocess.STDOUT, timeout=timeout)
    return proc.returncode, out.read_text()


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory) -> Path:
    """The tiny L datasets, built once for every run here."""
    home = tmp_path_factory.mktemp("resume_home")
    old = os.environ.get("SPADE_HOME")
    try:
        hydra.utils.instantiate(compose_row(ROW, home).data).prepare_data()
    finally:
        os.environ.pop("SPADE_HOME", None) if old is None else os.environ.__setitem__("SPADE_HOME", old)
    return home / "data"


def _client(home: Path):
    from mlflow import MlflowClient

    return MlflowClient(tracking_uri=f"sqlite:///{home}/logs/mlflow.db")


def _the_run(home: Path):
    client = _client(home)
    (run,) = client.search_runs([client.get_experiment_by_name("resume").experiment_id], filter_string=TOP_LEVEL_FILTER)
    return client, run


def test_kill_9_and_resume_tests_the_uninterrupted_runs_best_checkpoint(tmp_path: Path, data_dir: Path) -> None:
    """Resuming from ``last.ckpt`` into a new run folder made Lightning drop ``best_model_score`` ("dirpath
    has changed"), so the first epoch after the resume became "best" whatever its score. The checkpoint monitor
    is set to *maximise* the falling validation loss, so that the best epoch is an early one, before the kill."""
    args = ["-m", "spade.train", f"+experiment={ROW}", "trainer.max_epochs=4", "+trainer.limit_train_batches=3",
            "+trainer.limit_val_batches=2", "+trainer.limit_test_batches=2", "seed=7", f"paths.data_dir={data_dir}",
            "tags.table=resume", "callbacks.model_checkpoint.mode=max", *QUICK]
    home_a, home_b = tmp_path / "a", tmp_path / "b"
    run_a, run_b, run_b2 = tmp_path / "run_a", tmp_path / "run_b", tmp_path / "run_b2"
    code, out = _run([*args, f"hydra.run.dir={run_a}"], home_a)
    assert code == 0, out[-4000:]
    kill = ["+callbacks.kill._target_=test_command_processes.KillAtBatch", "+callbacks.kill.epoch=2",
            "+callbacks.kill.batch=1"]
    code, out = _run([*args, *kill, f"hydra.run.dir={run_b}"], home_b)
    assert code == -signal.SIGKILL, out[-4000:]  # killed in epoch 2, after the checkpoints of epochs 0 and 1
    from spade.models.modelfile import load_checkpoint

    # last.ckpt is epoch 1's, although epoch 1 did not improve (Lightning's save_last rewrites it only on improvement)
    assert load_checkpoint(run_b / "checkpoints" / "last.ckpt")["epoch"] == 1
    code, out = _run([*args, f"ckpt_path={run_b / 'checkpoints' / 'last.ckpt'}", f"hydra.run.dir={run_b2}"], home_b)
    assert code == 0, out[-4000:]

    (client_a, a), (client_b, b) = _the_run(home_a), _the_run(home_b)
    best_a = [x.path for x in client_a.list_artifacts(a.info.run_id, "checkpoints/best")]
    best_b = [x.path for x in client_b.list_artifacts(b.info.run_id, "checkpoints/best")]
    assert best_a == best_b, (best_a, best_b)  # the same best checkpoint was tested ...
    assert best_a[0].rsplit("/", 1)[-1] in ("epoch000.ckpt", "epoch001.ckpt"), best_a  # ... one from before the kill
    # ... with the same numbers (NaN where an untrained student extracts no path), the planner's figures included
    def figures(run) -> dict[str, str]:
        return {k: repr(v) for k, v in run.data.metrics.items() if k.startswith("test/")}

    assert figures(a) and any(k.startswith("test/planner/") for k in figures(a)) and figures(b) == figures(a)
    assert b.info.status == "FINISHED"
    val_steps = [m.step for m in client_b.get_metric_history(b.info.run_id, "val/loss_bc")]
    assert len(val_steps) == 4 and len(set(val_steps)) == 4, val_steps  # resumed after epoch 1: no step twice
    assert (run_b / "checkpoints" / best_a[0].rsplit("/", 1)[-1]).is_file()  # the interrupted run's folder is intact


# -- 7. annotation workers end with their parent -----------------------------------------------------------------------
def _children(pid: int) -> set[int]:
    out = set()
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            out.add(int(stat.parent.name))
    return out


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state not in ("Z", "X")


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM], ids=["kill-9", "sigterm"])
def test_annotation_workers_exit_with_their_parent(tmp_path: Path, sig: int) -> None:
    """After ``kill -9`` or SIGTERM of ``spade.annotate workers=2`` the two spawn workers and the resource
    tracker kept running, orphaned."""
    cmd = [sys.executable, "-m", "spade.annotate", "workers=2", "maps=[warehouse:1,office:1]", "num_instances=200000",
           "scenario.max_per_map=100000", f"out_dir={tmp_path / 'ds'}", "progress=false", "preview.enabled=false",
           f"hydra.run.dir={tmp_path / 'h'}"]
    proc = subprocess.Popen(cmd, cwd=REPO, env=_env(tmp_path), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    children: set[int] = set()
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and len(children) < 3:  # two workers and the resource tracker
            assert proc.poll() is None, "spade.annotate ended early"
            children = {c for c in _children(proc.pid) if _alive(c)}
            time.sleep(0.2)
        assert len(children) >= 3, children
        os.kill(proc.pid, sig)
        proc.wait(timeout=30)
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline and any(_alive(c) for c in children):
            time.sleep(0.2)
        left = sorted(c for c in children if _alive(c))
        assert left == [], f"orphaned processes still running: {left}"
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        for child in children | _children(proc.pid):  # never leave a worker behind, even when the test fails
            if _alive(child):
                try:
                    os.kill(child, signal.SIGKILL)
                except ProcessLookupError:
                    pass
    assert not (tmp_path / "ds").exists()


# -- part 2 as a user types it -----------------------------------------------------------------------------------------
def test_the_command_lines_fail_in_one_line_with_exit_2(tmp_path: Path) -> None:
    """The shorthands of ``python -m spade.plan`` / ``spade.annotate`` included, one ``error:`` line in seconds."""
    from spade.maps import OccupancyMap, save_ros_map

    import numpy as np

    yaml_path = save_ros_map(OccupancyMap(np.ones((50, 50), np.uint8), 0.1, name="m"), tmp_path / "m.yaml")
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep")
    for args, words in (
        (["-m", "spade.plan", str(yaml_path), "start=0,1,0", "goal=0,1", f"model={tmp_path}"], "not a model file"),
        (["-m", "spade.annotate", "preset=lshape", "overwrite=true", f"out_dir={mine}"], "never other files"),
        (["-m", "spade.data.verify", str(mine)], "holds no manifest.json"),
    ):
        start = time.monotonic()
        code, out = _run([*args, *([f"hydra.run.dir={tmp_path / 'h'}"] if "verify" not in args[1] else [])],
                         tmp_path / "home", timeout=120)
        assert code == 2, out
        lines = [line for line in out.splitlines() if line.strip()]
        assert "Traceback" not in out and sum(line.startswith("error: ") for line in lines) == 1, out
        assert any(words in line for line in lines), out
        print(f"{args[1]}: exit 2 after {time.monotonic() - start:.1f} s")
    assert (mine / "notes.txt").read_text() == "keep"
