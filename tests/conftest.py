"""Shared pytest fixtures."""

from __future__ import annotations

import os
from pathlib import Path

import pytest


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
    for key, row in (("cond", "expert_cond_L"), ("uncond", "expert_uncond_L"), ("student", "t1_medium_bc_L")):
        cfg = compose_row(row, spade_home, "logger=none", "trainer.max_steps=2", "trainer.max_epochs=1",
                          "test=false", "+trainer.limit_val_batches=1", "data.eval_batch_size=8", "model.grid_size=0",
                          "callbacks.model_info.latency_runs=0")
        _, objects = train(cfg)
        path = spade_home / f"{key}.ckpt"
        objects["trainer"].save_checkpoint(path)
        out[key] = str(path)
    del hydra
    return out


@pytest.fixture(autouse=True)
def _isolated_mlflow_tracking_uri():
    """Each test starts without ``MLFLOW_TRACKING_URI`` and leaves none behind.

    ``mlflow.set_tracking_uri`` (called by in-process training) exports the URI into ``os.environ`` so that
    child processes inherit it; without this a later test's ``spade.train`` subprocess would log into an
    earlier test's store instead of the one its ``SPADE_HOME`` names.
    """
    old = os.environ.pop("MLFLOW_TRACKING_URI", None)
    try:
        yield
    finally:
        os.environ.pop("MLFLOW_TRACKING_URI", None)
        if old is not None:
            os.environ["MLFLOW_TRACKING_URI"] = old
