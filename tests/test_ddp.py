"""DDP through the real entry point (2 CPU processes, gloo) and the GPU trainer configs."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import hydra
import numpy as np
import pytest
import torch

from spade.training.callbacks import ChannelsLast
from spade.training.student_module import StudentModule
from spade.utils.config import compose_config
from training_helpers import compose_row
from spade.tracking.predictors import TOP_LEVEL_FILTER

REPO = Path(__file__).resolve().parents[1]
ROW = "t1_small_bc_L"


def _mlflow_metrics(tracking_uri: str) -> dict[str, float]:
    from mlflow import MlflowClient

    client = MlflowClient(tracking_uri=tracking_uri)
    experiment = client.get_experiment_by_name("table1")
    runs = client.search_runs([experiment.experiment_id], filter_string=TOP_LEVEL_FILTER)
    assert len(runs) == 1, f"expected the DDP run to be one MLflow run, found {len(runs)}"
    return dict(runs[0].data.metrics)


@pytest.mark.slow  # DDP: two spade.train processes; the configs compose in test_gpu_trainer_configs_compose
def test_ddp_two_cpu_processes_sync_metrics_through_the_entry_point(spade_home: Path, tmp_path: Path) -> None:
    # The datasets (built once per session); an odd test set: a padding sampler would repeat one instance.
    dm = hydra.utils.instantiate(compose_row(ROW, spade_home).data)
    dm.prepare_data()
    dm.setup("fit")
    n_test = len(dm.test_set) - (1 - len(dm.test_set) % 2)
    n_val = len(dm.val_set)

    run_dir, uri = tmp_path / "run", f"sqlite:///{tmp_path}/mlflow.db"
    cmd = [
        sys.executable, "-m", "spade.train", f"+experiment={ROW}", "scale=tiny",
        "trainer=ddp", "trainer.accelerator=cpu", "trainer.devices=2", "trainer.max_epochs=1", "trainer.log_every_n_steps=1",
        "+trainer.limit_train_batches=2", "trainer.enable_progress_bar=false", f"+data.max_test_instances={n_test}",
        "callbacks.model_info.latency_runs=0", "registry.prefix=null",
        f"hydra.run.dir={run_dir}", f"paths.mlflow_tracking_uri={uri}",
    ]
    env = {**os.environ, "SPADE_HOME": str(spade_home), "OMP_NUM_THREADS": "1"}
    proc = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=400)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-4000:]
    assert "GLOBAL_RANK: 0, MEMBER: 1/2" in out and "GLOBAL_RANK: 1, MEMBER: 2/2" in out, out[-4000:]

    logged = _mlflow_metrics(uri)
    # Synced over both ranks, each instance once (not half the set, not padded with a repeat).
    assert logged["test/instances"] == n_test
    assert logged["val/instances"] == n_val
    assert np.isfinite(logged["train/loss_bc"]) and np.isfinite(logged["val/loss_bc"])

    # The same checkpoint tested by one process gives the values the two processes logged.
    ckpt = run_dir / "checkpoints" / "epoch000.ckpt"
    assert ckpt.is_file(), sorted(p.name for p in run_dir.rglob("*"))
    from spade.evaluate import evaluate

    cfg = compose_config("evaluate", [f"ckpt_path={ckpt}", f"paths.root_dir={spade_home}", "scale=tiny", "data=lshape", "logger=none",
                                      f"+data.max_test_instances={n_test}", "trainer.enable_progress_bar=false",
                                      f"paths.output_dir={tmp_path}/eval"])
    single = evaluate(cfg)
    assert single["test/instances"] == n_test
    # the run's own test figures (the baselines' live in its child runs since SPADE's MLFlowLogger)
    test_keys = sorted(k for k in single if k.startswith("test/") and not k.startswith("test/baseline/"))
    assert test_keys == sorted(k for k in logged if k.startswith("test/"))
    for key in test_keys:
        np.testing.assert_allclose(logged[key], single[key], rtol=1e-4, atol=1e-6, err_msg=key)


def test_gpu_trainer_configs_compose() -> None:
    gpu = compose_config("train", ["trainer=gpu"])
    assert gpu.trainer.accelerator == "gpu" and gpu.trainer.precision == "bf16-mixed"
    assert gpu.callbacks.channels_last._target_ == "spade.training.callbacks.ChannelsLast"
    assert "model_checkpoint" in gpu.callbacks  # added to the callbacks group, not replacing it
    ddp = compose_config("train", ["trainer=ddp_gpu"])
    assert (ddp.trainer.strategy, ddp.trainer.sync_batchnorm, ddp.trainer.precision) == ("ddp", True, "bf16-mixed")
    multi = compose_config("train", ["trainer=ddp_multinode", "trainer.num_nodes=4"])
    assert multi.trainer.num_nodes == 4 and multi.trainer.strategy == "ddp" and "channels_last" in multi.callbacks
    text = (REPO / "conf" / "trainer" / "ddp_multinode.yaml").read_text()
    assert "torchrun" in text and "srun" in text
    cpu = compose_config("train", ["trainer=ddp"])
    assert cpu.trainer.strategy == "ddp" and cpu.trainer.sync_batchnorm is False and "channels_last" not in cpu.callbacks


def test_channels_last_callback_keeps_the_outputs() -> None:
    torch.manual_seed(0)
    module = StudentModule(size="small").eval()
    batch = {"state": torch.rand(2, 3, 32, 32), "path": torch.rand(2, 1, 32, 32), "resolution": torch.ones(2)}
    with torch.no_grad():
        reference = module(batch["state"])
    callback = ChannelsLast()
    callback.setup(None, module, "fit")
    callback.convert(batch)
    convs = [m.weight for m in module.modules() if isinstance(m, torch.nn.Conv2d)]
    assert convs and all(w.is_contiguous(memory_format=torch.channels_last) for w in convs)
    assert batch["state"].is_contiguous(memory_format=torch.channels_last)
    assert not batch["state"].is_contiguous()
    with torch.no_grad():
        out = module(batch["state"])
    torch.testing.assert_close(out, reference, rtol=1e-4, atol=1e-5)
