"""The package as a user installs it: a wheel built from the repository, installed into a folder of its
own and run from another folder, composes every entry point's config from the copy it carries (``spade/conf``,
:data:`spade.paths.CONF_DIR`) and ships the files SPADE needs at run time."""

from __future__ import annotations

import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.mark.slow  # builds a wheel (pip, build isolation: a registry) and starts a few Python processes
def test_an_installed_wheel_runs_its_entry_points_from_any_folder(tmp_path: Path) -> None:
    wheels, site, elsewhere = tmp_path / "wheels", tmp_path / "site", tmp_path / "elsewhere"
    elsewhere.mkdir()
    build = subprocess.run([sys.executable, "-m", "pip", "wheel", str(REPO), "--no-deps", "-q", "-w", str(wheels)],
                           capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert build.returncode == 0, build.stderr[-3000:]
    (wheel,) = wheels.glob("spade-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    conf = {p.relative_to(REPO / "conf").as_posix() for p in (REPO / "conf").rglob("*.yaml")}
    assert {f"spade/conf/{c}" for c in conf} <= names  # every config
    assert any(n.startswith("spade/models/weights/") and n.endswith(".ckpt") for n in names)  # the shipped expert
    assert "spade/sketching/static/index.html" in names and "spade/metrics/shape_features_v1.npz" in names
    assert "spade/ros/foxglove_layout.json" in names  # the Foxglove layout (spade.ros.live.LAYOUT)
    install = subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target", str(site),
                              str(wheel)], capture_output=True, text=True, timeout=600)
    assert install.returncode == 0, install.stderr[-3000:]
    env = {**{k: v for k, v in os.environ.items() if k not in ("MLFLOW_TRACKING_URI", "HYDRA_FULL_ERROR")},
           "PYTHONPATH": str(site), "SPADE_HOME": str(elsewhere)}

    def run(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, *args], capture_output=True, text=True, timeout=300, cwd=elsewhere,
                              env=env)

    where = run("-c", "import spade, spade.paths as p; print(spade.__file__); print(p.CONF_DIR)")
    assert where.returncode == 0, where.stderr[-3000:]
    assert where.stdout.splitlines() == [str(site / "spade" / "__init__.py"), str(site / "spade" / "conf")]
    job = run("-m", "spade.train", "+experiment=smoke", "--cfg", "job")
    assert job.returncode == 0 and "run_name: smoke" in job.stdout, job.stderr[-3000:]
    refused = run("-m", "spade.report", f"tracking_uri=sqlite:///{elsewhere}/none/mlflow.db")
    assert refused.returncode == 2 and "no MLflow store" in refused.stderr, refused.stderr[-3000:]
