"""sweeps/: the Optuna, joblib and SLURM configs compose; parallel runs against one `mlflow server` lose nothing."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

from spade.utils.config import compose_config
from spade.tracking.predictors import TOP_LEVEL_FILTER

REPO = Path(__file__).resolve().parents[1]
SWEEPS = REPO / "sweeps"
PLUGINS = {"optuna": "hydra_plugins.hydra_optuna_sweeper", "joblib": "hydra_plugins.hydra_joblib_launcher",
           "submitit": "hydra_plugins.hydra_submitit_launcher"}
# One "epoch" of 2 training batches, one validation batch (so that optimized_metric is logged), one test batch.
TINY = ["scale=tiny", "trainer.max_epochs=1", "++trainer.limit_train_batches=2", "++trainer.limit_val_batches=1",
        "++trainer.limit_test_batches=1", "++trainer.num_sanity_val_steps=0", "trainer.enable_progress_bar=false"]
TEST_KEYS = {"test/ape_cm", "test/hd19", "test/failure_rate", "model/params"}


def _plugin(name: str) -> None:
    pytest.importorskip(PLUGINS[name], reason=f"the {name} Hydra plugin is not installed (pip install -e '.[sweeps]')")


def _compose(*overrides: str):
    return compose_config("train", [f"hydra.searchpath=[file://{SWEEPS}]", *overrides], return_hydra_config=True)


def test_conddbc_lambda_search_composes() -> None:
    _plugin("optuna")
    cfg = _compose("+search=conddbc_lambda", "model.margin.lambda_dm=0.3")
    sweeper = cfg.hydra.sweeper
    assert sweeper._target_.endswith("OptunaSweeper") and cfg.hydra.mode.name == "MULTIRUN"
    assert sweeper.params["model.margin.lambda_dm"] == "tag(log, interval(0.01, 10.0))"
    assert cfg.hydra.runtime.choices.margin == "cond_dbc" and cfg.model.size == "medium"
    assert cfg.run_name == "t1_medium_conddbc_L_lambda0.3" and cfg.tags.table == "sweep_conddbc_lambda"
    assert cfg.registry.prefix is None  # trials never replace the table row's registered model
    assert cfg.requires.expert.experiment == "cond_expert_L"


@pytest.mark.parametrize("launcher,plugin,target", [("local", "joblib", "JoblibLauncher"),
                                                    ("slurm", "submitit", "SlurmLauncher")])
def test_launchers_compose_with_a_table(launcher: str, plugin: str, target: str) -> None:
    _plugin(plugin)
    cfg = _compose("+experiment=ablation_finetune", f"hydra/launcher={launcher}")
    assert cfg.hydra.launcher._target_.endswith(target)
    assert cfg.hydra.sweeper.params.experiment.count(",") == 2
    if launcher == "local":
        assert cfg.hydra.launcher.n_jobs == 2
    else:
        assert cfg.hydra.launcher.gpus_per_node == 1 and cfg.hydra.launcher.array_parallelism > 1


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory):
    """`mlflow server` on a fresh SQLite database, plus a SPADE_HOME whose tiny datasets are already built."""
    home = tmp_path_factory.mktemp("sweep_home")
    port = _free_port()
    log = open(home / "mlflow-server.log", "w")
    proc = subprocess.Popen(
        [sys.executable, "-m", "mlflow", "server", "--backend-store-uri", f"sqlite:///{home}/mlflow.db",
         "--default-artifact-root", str(home / "mlartifacts"), "--host", "127.0.0.1", "--port", str(port),
         "--workers", "1"],
        stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    uri = f"http://127.0.0.1:{port}"
    try:
        # Datasets first, in this process: the parallel jobs would otherwise each generate the same ones.
        import hydra

        for data in ("lshape", "ushape"):
            cfg = compose_config("train", [f"data={data}", "scale=tiny", f"paths.root_dir={home}", "paths.output_dir=."])
            hydra.utils.instantiate(cfg.data).prepare_data()
        deadline = time.time() + 300
        while True:
            try:
                with urllib.request.urlopen(f"{uri}/health", timeout=2) as r:
                    if r.status == 200:
                        break
            except OSError:
                pass
            assert proc.poll() is None and time.time() < deadline, (home / "mlflow-server.log").read_text()[-3000:]
            time.sleep(1)
        yield {"uri": uri, "home": home}
    finally:
        os.killpg(proc.pid, signal.SIGTERM)
        proc.wait(timeout=60)
        log.close()


def _start(args: list[str], server: dict) -> subprocess.Popen:
    env = {**os.environ, "SPADE_HOME": str(server["home"]), "MLFLOW_TRACKING_URI": server["uri"],
           "PYTHONUNBUFFERED": "1"}
    return subprocess.Popen([sys.executable, "-m", "spade.train", *args], cwd=REPO, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def _finish(proc: subprocess.Popen) -> str:
    out, _ = proc.communicate(timeout=1200)
    assert proc.returncode == 0, out[-4000:]
    return out


@pytest.mark.slow  # an mlflow server and parallel spade.train processes; the configs compose in the tests above
def test_two_parallel_jobs_into_one_server_both_complete(server: dict) -> None:
    """Two trainings start together into an empty store (both create the `table1` experiment) and both finish."""
    from mlflow import MlflowClient

    procs = [_start([f"+experiment={row}", *TINY], server) for row in ("t1_small_bc_L", "t1_small_bc_U")]
    for proc in procs:
        _finish(proc)
    client = MlflowClient(tracking_uri=server["uri"])
    runs = client.search_runs([client.get_experiment_by_name("table1").experiment_id], filter_string=TOP_LEVEL_FILTER)
    assert sorted(r.info.run_name for r in runs) == ["t1_small_bc_L", "t1_small_bc_U"]
    for run in runs:
        assert run.info.status == "FINISHED" and TEST_KEYS <= set(run.data.metrics), run.data.metrics
        assert {"checkpoints", "config"} <= {a.path for a in client.list_artifacts(run.info.run_id)}
    assert len(client.search_model_versions("name LIKE 'spade-student-bc-%-small-%'")) == 2


@pytest.mark.slow
def test_optuna_search_with_joblib_runs_two_trials_in_parallel(server: dict) -> None:
    """The lambda search, two trials at once (joblib, n_jobs=2), reporting to the server; its prerequisite (the
    conditional expert) is registered first, so that the parallel trials find it rather than train it twice."""
    _plugin("optuna")
    _plugin("joblib")
    from mlflow import MlflowClient

    _finish(_start(["+experiment=cond_expert_L", *TINY, "test=false"], server))
    sweep_dir = server["home"] / "sweep"
    _finish(_start(["-m", "--config-dir", str(SWEEPS), "+search=conddbc_lambda", "hydra/launcher=local",
                          "hydra.sweeper.n_jobs=2", "hydra.sweeper.n_trials=2", "model.size=small",
                          "prerequisites=error", f"hydra.sweep.dir={sweep_dir}", *TINY], server))
    client = MlflowClient(tracking_uri=server["uri"])
    runs = client.search_runs([client.get_experiment_by_name("sweep_conddbc_lambda").experiment_id], filter_string=TOP_LEVEL_FILTER)
    assert len(runs) == 2 and all(r.info.status == "FINISHED" and TEST_KEYS <= set(r.data.metrics) for r in runs)
    lambdas = sorted(float(r.data.tags["lambda"]) for r in runs)
    assert all(0.01 <= v <= 10.0 for v in lambdas) and lambdas[0] != lambdas[1]
    assert all(r.info.run_name.startswith("t1_medium_conddbc_L_lambda") for r in runs)
    results = (sweep_dir / "optimization_results.yaml").read_text()
    assert "best_params" in results and "model.margin.lambda_dm" in results


@pytest.mark.slow
def test_a_table_row_runs_through_submitits_local_executor_into_the_server(server: dict) -> None:
    """Scale-out that runs, not only composes: one row of Table 1 as a job of the submitit launcher (its local
    executor: the job pickled, started as its own process and unpickled, as on a SLURM cluster), reporting to the
    MLflow server; the run finishes with its test metrics and submitit's own logs hold the job's output."""
    _plugin("submitit")
    from mlflow import MlflowClient

    sweep_dir = server["home"] / "submitit"
    out = _finish(_start(["--config-dir", str(SWEEPS), "+experiment=table1", "rows=[t1_small_bc_L]", "seeds=[7]",
                          "hydra/launcher=slurm_local", f"hydra.sweep.dir={sweep_dir}", *TINY], server))
    assert "1 rows x 1 seed(s)" in out, out[-3000:]
    client = MlflowClient(tracking_uri=server["uri"])
    runs = [r for r in client.search_runs([client.get_experiment_by_name("table1").experiment_id], filter_string=TOP_LEVEL_FILTER)
            if r.data.params.get("cfg/seed") == "7"]
    assert [r.info.run_name for r in runs] == ["t1_small_bc_L"]
    assert runs[0].info.status == "FINISHED" and TEST_KEYS <= set(runs[0].data.metrics), runs[0].data.metrics
    logs = sorted((sweep_dir / ".submitit").rglob("*_log.out"))
    assert logs and any("t1_small_bc_L" in p.read_text() for p in logs), sorted(sweep_dir.rglob("*"))
