"""Students as MLflow Models: spade.export register=NAME logs the ONNX export (ONNX flavour, signature, window
metadata) and sets the alias; spade.plan and spade.ros load models:/NAME@champion from that registry."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_export_registers_and_plan_loads_models_uri(tmp_path: Path, maps_dir: Path,
                                                    monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("onnxruntime")
    from ros_support import GOAL, MAP, POSE, student_files

    ckpt, _ = student_files(tmp_path)
    store = f"sqlite:///{tmp_path / 'mlflow.db'}"
    env = {**os.environ, "PYTHONPATH": str(REPO), "SPADE_HOME": str(tmp_path / "home"), "MLFLOW_TRACKING_URI": store}
    export = subprocess.run([sys.executable, "-m", "spade.export", f"ckpt_path={ckpt}",
                             f"out_path={tmp_path / 'registered.onnx'}", "latency_runs=0", "register=spade-student"],
                            cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert export.returncode == 0, export.stdout + export.stderr
    assert "registered: models:/spade-student@champion (version 1" in export.stdout

    import mlflow

    client = mlflow.MlflowClient(tracking_uri=store, registry_uri=store)
    version = client.get_model_version_by_alias("spade-student", "champion")
    assert str(version.version) == "1"
    # An earlier in-process test may have set mlflow's process-wide URIs (they win over the environment): this
    # store's, for this look-up only (the registry follows the tracking URI).
    from spade.deploy.mlflow_models import using_tracking_uri

    with using_tracking_uri(store):
        model = mlflow.models.get_model_info("models:/spade-student@champion")
    assert "onnx" in model.flavors
    assert model.signature.inputs.to_dict()[0]["tensor-spec"]["shape"] in ([-1, 3, 64, 64], (-1, 3, 64, 64))
    assert model.signature.outputs.to_dict()[0]["tensor-spec"]["shape"] in ([-1, 1, 64, 64], (-1, 1, 64, 64))
    assert model.metadata["spade"]["resolution_m"] == 0.1 and model.metadata["spade"]["frame"]["kind"] == "robot"

    args = [sys.executable, "-m", "spade.plan", str(maps_dir.joinpath(*MAP)), "start={},{},{}".format(*POSE),
            "goal={},{}".format(*GOAL[:2])]
    by_uri = subprocess.run([*args, "model=models:/spade-student@champion", f"out={tmp_path / 'a.png'}"],
                            cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert by_uri.returncode == 0, by_uri.stdout + by_uri.stderr
    by_file = subprocess.run([*args, f"model={tmp_path / 'registered.onnx'}", f"out={tmp_path / 'b.png'}"],
                             cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert by_file.returncode == 0, by_file.stderr
    def waypoints(stdout: str) -> np.ndarray:  # the "x y" lines between "# x_m y_m" and the picture line
        lines = stdout.split("# x_m y_m\n", 1)[1].split("\n# ", 1)[0].splitlines()
        return np.array([line.split() for line in lines], dtype=float)

    points = [waypoints(run.stdout) for run in (by_uri, by_file)]
    assert points[0].shape == (64, 2)
    np.testing.assert_allclose(points[0], points[1])  # the registered model is the exported file

    unknown = subprocess.run([*args, "model=models:/spade-student@nobody", f"out={tmp_path / 'c.png'}"],
                             cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert unknown.returncode == 2 and unknown.stderr.startswith("error: models:/spade-student@nobody: cannot be "
                                                                 "fetched from the MLflow registry")
