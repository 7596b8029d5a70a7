"""Shared pytest fixtures."""

from __future__ import annotations

import logging
import os
import runpy
import sys
from pathlib import Path

import pytest
from hydra.core.global_hydra import GlobalHydra

from factories import student_checkpoint


@pytest.fixture(scope="session")
def maps_dir() -> Path:
    """The folder of real ROS maps named by ``SPADE_MAPS_DIR``; skipped when absent, failed under SPADE_REQUIRE_MAPS=1."""
    required = os.environ.get("SPADE_REQUIRE_MAPS") == "1"  # set by .ci/run: CI must not skip these tests
    value = os.environ.get("SPADE_MAPS_DIR")
    if not value:
        message = "SPADE_MAPS_DIR is not set (point it at a folder of ROS map yamls, e.g. ../shared/maps)"
        pytest.fail(message) if required else pytest.skip(message)
    path = Path(value).expanduser()
    if not path.is_dir() or not any(path.rglob("*.yaml")):
        message = f"SPADE_MAPS_DIR={path} holds no ROS map yaml files"
        pytest.fail(message) if required else pytest.skip(message)
    return path


@pytest.fixture(scope="session")
def spade_home(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A SPADE_HOME for the training tests, holding the tiny datasets every row shares (built on first use)."""
    home = tmp_path_factory.mktemp("spade_home")
    old = os.environ.get("SPADE_HOME")
    os.environ["SPADE_HOME"] = str(home)
    yield home
    if old is None:
        os.environ.pop("SPADE_HOME", None)
    else:
        os.environ["SPADE_HOME"] = old


@pytest.fixture(scope="session")
def tiny_checkpoints(spade_home: Path) -> dict[str, str]:
    """Checkpoints of a tiny conditional expert, a tiny unconditional expert and a medium student (L shape)."""
    import hydra

    from spade.experiments.run import train
    from training_helpers import compose_row

    out = {}
    for key, row in (("cond", "cond_expert_L"), ("uncond", "uncond_expert_L"), ("student", "t1_medium_bc_L")):
        cfg = compose_row(row, spade_home, "logger=none", "trainer.max_steps=2", "trainer.max_epochs=1",
                          "test=false", "+trainer.limit_val_batches=1", "data.eval_batch_size=8", "model.grid_size=0",
                          "callbacks.model_info.latency_runs=0")
        _, objects = train(cfg)
        path = spade_home / f"{key}.ckpt"
        objects["trainer"].save_checkpoint(path)
        out[key] = str(path)
    del hydra
    return out


#: Environment variables that the libraries a test drives set themselves (names or prefixes): Lightning's
#: ``seed_everything`` records the seed, torch sets its own on the first import of some modules, MLflow keeps its
#: telemetry session id. Neither restored nor reported. ``MLFLOW_TRACKING_URI`` (exported by ``mlflow.set_tracking_uri`` for child processes) is removed
#: after each test: a later test's ``spade.train`` subprocess must not log into an earlier test's store.
LIBRARY_SET_ENV = ("PL_GLOBAL_SEED", "PL_SEED_WORKERS", "PYTORCH_", "TORCHINDUCTOR_", "TORCH_", "KMP_",
                   "CUBLAS_WORKSPACE_CONFIG", "_MLFLOW_TELEMETRY_")
#: Set by pytest itself around every phase of a test.
PYTEST_ENV = "PYTEST_CURRENT_TEST"


def _owned_by_a_library(key: str) -> bool:
    return key == PYTEST_ENV or key.startswith(LIBRARY_SET_ENV)


@pytest.fixture(autouse=True)
def _environment_left_as_found():
    """Each test starts without ``MLFLOW_TRACKING_URI`` and leaves ``os.environ`` as it found it.

    A test that sets a variable itself must use ``monkeypatch.setenv`` (undone after it); one that leaves a change
    fails, naming the variables, after the environment is restored for the tests that follow. Session fixtures
    (``spade_home``) are set up before this snapshot and undo their own change.
    """
    old_uri = os.environ.pop("MLFLOW_TRACKING_URI", None)
    old_registry = os.environ.pop("MLFLOW_REGISTRY_URI", None)
    before = dict(os.environ)
    try:
        yield
    finally:
        os.environ.pop("MLFLOW_TRACKING_URI", None)
        os.environ.pop("MLFLOW_REGISTRY_URI", None)  # exported by mlflow.set_registry_uri, as the tracking URI
        after = dict(os.environ)
        changed = sorted(k for k in set(before) | set(after)
                         if before.get(k) != after.get(k) and not _owned_by_a_library(k))
        for key in changed:
            if key in before:
                os.environ[key] = before[key]
            else:
                del os.environ[key]
        if old_uri is not None:
            os.environ["MLFLOW_TRACKING_URI"] = old_uri
        if old_registry is not None:
            os.environ["MLFLOW_REGISTRY_URI"] = old_registry
    if changed:
        pytest.fail(f"the test left os.environ changed ({', '.join(changed)}); set variables with "
                    "monkeypatch.setenv so that they are undone")


@pytest.fixture
def run_main(monkeypatch, tmp_path: Path, capsys):
    """``run_main("spade.plan", [...])`` -> (exit status, stderr): the entry point's Hydra main in this process."""
    monkeypatch.delenv("HYDRA_FULL_ERROR", raising=False)
    monkeypatch.setenv("SPADE_HOME", str(tmp_path / "home"))
    monkeypatch.setenv("OMP_WAIT_POLICY", "PASSIVE")  # what spade.train sets as a command (undone after the test)

    def drop_log_handlers() -> None:
        """Hydra points the root logger at this test's captured stderr; a later test's lazy import that logs
        before its own Hydra run (numexpr's thread count, under mlflow) would write to that closed stream and print
        "--- Logging error ---" into the next refusal: each run starts and ends without them."""
        for handler in list(logging.root.handlers):
            logging.root.removeHandler(handler)

    def run(module: str, args: list[str], hydra: bool = True) -> tuple[int, str]:
        GlobalHydra.instance().clear()
        drop_log_handlers()
        extra = [f"hydra.run.dir={tmp_path / 'hydra'}"] if hydra else []
        monkeypatch.setattr(sys, "argv", [module, *args, *extra])
        capsys.readouterr()
        code = 0
        try:  # as python -m runs it (Hydra finds conf/ from the module's file when it runs as __main__)
            runpy.run_module(module, run_name="__main__", alter_sys=True)
        except SystemExit as exc:
            code = exc.code
        finally:
            GlobalHydra.instance().clear()
            drop_log_handlers()
        return int(code or 0), capsys.readouterr().err

    return run


@pytest.fixture(scope="module")
def real_export(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A real ONNX export of an untrained small student (64 px robot-frame windows)."""
    pytest.importorskip("onnxruntime")
    from spade.deploy.export import export_student

    folder = tmp_path_factory.mktemp("export")
    return export_student(student_checkpoint(folder / "student.ckpt"), folder / "student.onnx", "onnx",
                          latency_runs=0).out_path
