"""The notebooks: committed without outputs, and they run top to bottom on a tiny SPADE_HOME with one tiny run."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import nbformat
import pytest

REPO = Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((REPO / "notebooks").glob("*.ipynb"))


def test_there_are_the_two_notebooks() -> None:
    assert [p.name for p in NOTEBOOKS] == ["01_datasets.ipynb", "02_results.ipynb"]


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_committed_notebooks_are_stripped(path: Path) -> None:
    nb = nbformat.read(path, as_version=4)
    nbformat.validate(nb)
    for i, cell in enumerate(nb.cells):
        if cell.cell_type == "code":
            assert cell.outputs == [] and cell.execution_count is None, (
                f"{path.name} cell {i} holds outputs; strip them before committing "
                f"(jupyter nbconvert --clear-output --inplace {path.relative_to(REPO)})"
            )


@pytest.fixture(scope="module")
def tiny_home(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A SPADE_HOME with tiny datasets and one finished Table 1 student run (2 training steps)."""
    home = tmp_path_factory.mktemp("nb_home")
    env = {**os.environ, "SPADE_HOME": str(home), "PYTHONUNBUFFERED": "1"}
    env.pop("MLFLOW_TRACKING_URI", None)
    args = ["+experiment=t1_small_bc_L", "scale=tiny", "trainer.max_epochs=1", "++trainer.limit_train_batches=2",
            "++trainer.limit_val_batches=1", "++trainer.limit_test_batches=1", "++trainer.num_sanity_val_steps=0",
            "trainer.enable_progress_bar=false"]
    proc = subprocess.run([sys.executable, "-m", "spade.train", *args], cwd=REPO, env=env, capture_output=True,
                          text=True, timeout=900)
    assert proc.returncode == 0, (proc.stdout + proc.stderr)[-4000:]
    return home


@pytest.mark.slow  # a spade.train process and two Jupyter kernels; the stripped check stays fast
@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_executes(path: Path, tiny_home: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from nbclient import NotebookClient

    monkeypatch.setenv("SPADE_HOME", str(tiny_home))
    monkeypatch.setenv("SPADE_SCALE", "tiny")
    monkeypatch.setenv("SPADE_TABLES", "table1,table2")
    monkeypatch.setenv("SPADE_NB_INSTANCES", "3")
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    monkeypatch.delenv("SPADE_DATA_DIR", raising=False)
    monkeypatch.delenv("SPADE_ROW", raising=False)
    nb = nbformat.read(path, as_version=4)
    NotebookClient(nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(path.parent)}}).execute()
    outputs = [o for cell in nb.cells for o in cell.get("outputs", [])]
    assert not [o for o in outputs if o.output_type == "error"]
    images = [o for o in outputs if "image/png" in o.get("data", {})]
    text = "".join(o.get("text", "") for o in outputs if o.output_type == "stream")
    if path.name.startswith("01"):
        assert len(images) >= 4  # instances per dataset, shape variations, maps
    else:
        assert "t1_small_bc_L: run" in text and "failed extraction" in text
        assert len(images) >= 4  # two table charts, predictions, APE-coloured paths
