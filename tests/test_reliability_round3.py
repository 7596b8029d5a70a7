"""Reliability, third round (issue 51): the wrong cases of the probe, reproduced, and the new behaviour.

- default output paths are checked as explicit ones are (``spade.export``'s export beside the checkpoint,
  ``spade.report``'s pages, ``spade.bench``'s JSON), and an empty path is refused instead of the filesystem root;
- a dataset manifest without its ``manifest_sha256`` is refused by ``verify`` and by loading;
- an ONNX graph carrying a copy of a real export's ``spade`` metadata is refused by the planner (torch and
  torch-free), ``spade.plan`` and the sketch server; an export from before the check opens with a warning.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from factories import write_synthetic
from test_reliability_outputs import digest, one_error_line, run_main, student_checkpoint  # noqa: F401 - a fixture

REPO = Path(__file__).resolve().parents[1]


# -- 2. a manifest without its checksum ------------------------------------------------------------------------------
def _strip_checksum(root: Path) -> Path:
    """The probe's edit: resolution and the generator record changed, ``manifest_sha256`` deleted."""
    manifest = root / "manifest.json"
    raw = json.loads(manifest.read_text())
    raw["resolution"] = 0.1
    raw["generator"]["seed"] = 999
    del raw["manifest_sha256"]
    manifest.write_text(json.dumps(raw))
    return manifest


def test_a_manifest_without_its_checksum_is_refused_by_verify_and_loading(tmp_path: Path) -> None:
    """Issue 51: a manifest whose resolution and generator record were edited and whose ``manifest_sha256`` was
    deleted verified "OK" and loaded. Now both refuse it, naming the file and the fix (regenerate)."""
    from spade.data import DatasetError, PathDataset
    from spade.data.verify import verify

    root = tmp_path / "ds"
    write_synthetic(root, n=4)
    assert verify(root) == [] and len(PathDataset(root)) == 4  # as written: sound
    manifest = _strip_checksum(root)
    (problem,) = verify(root)
    assert str(manifest) in problem and "no manifest_sha256" in problem and "Re-generate the dataset" in problem
    with pytest.raises(DatasetError, match="no manifest_sha256") as info:
        PathDataset(root)
    assert str(manifest) in str(info.value)


@pytest.mark.slow  # a python -m spade.data.verify process
def test_verify_command_reports_the_missing_checksum(tmp_path: Path) -> None:
    root = tmp_path / "ds"
    write_synthetic(root, n=3)
    _strip_checksum(root)
    proc = subprocess.run([sys.executable, "-m", "spade.data.verify", str(root)], cwd=REPO, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert "OK" not in proc.stdout and "no manifest_sha256" in proc.stdout


# -- 1. default output paths, checked like explicit ones; no empty path -----------------------------------------------
def spade_onnx(path: Path, metadata: dict | None = None, channels: int = 3) -> Path:
    """An ONNX Identity graph carrying ``metadata`` as its ``spade`` entry: a file SPADE's output check takes for
    an export of its own (its ``spade`` entry has a role), and, with a real export's metadata copied in, the
    forged model of the probe. ``state`` (N, channels, 64, 64) -> ``logits`` (the same)."""
    onnx = pytest.importorskip("onnx")
    from onnx import TensorProto, helper

    dims = ["N", channels, 64, 64]
    graph = helper.make_graph([helper.make_node("Identity", ["state"], ["logits"])], "forged",
                              [helper.make_tensor_value_info("state", TensorProto.FLOAT, dims)],
                              [helper.make_tensor_value_info("logits", TensorProto.FLOAT, dims)])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    entry = model.metadata_props.add()
    entry.key, entry.value = "spade", json.dumps(metadata or {"role": "student"})
    onnx.save(model, str(path))
    return path


def test_export_checks_its_default_output_beside_the_checkpoint(tmp_path: Path, run_main) -> None:
    """Issue 51: ``spade.export ckpt_path=DIR/student.ckpt`` replaced a user's own ``DIR/student.onnx`` (and with
    ``format=torchscript`` a text file ``student.pt``) and exited 0; a rerun replaced its own export without
    ``overwrite=true``. The default path is now checked as ``out_path=`` is, before any work."""
    from spade.experiments.config_checks import validate_export_config
    from spade.utils.config import compose_config

    ckpt = student_checkpoint(tmp_path / "student.ckpt")
    mine_onnx, mine_pt = tmp_path / "student.onnx", tmp_path / "student.pt"
    mine_onnx.write_text("my own model notes")
    mine_pt.write_text("my own TorchScript notes")
    before = {p: digest(p) for p in (mine_onnx, mine_pt)}
    for args in ([], ["overwrite=true"], ["format=torchscript"], ["format=torchscript", "overwrite=true"]):
        code, err = run_main("spade.export", [f"ckpt_path={ckpt}", "latency_runs=0", *args])
        assert code == 2, err
        line = one_error_line(err)
        target = mine_pt if "format=torchscript" in args else mine_onnx
        assert f"out_path={target} (the default" in line and "was not written by SPADE" in line
        assert "choose another out_path" in line
    assert {p: digest(p) for p in before} == before
    # an export of SPADE's there (its `spade` entry): replaced only with overwrite=true
    mine_onnx.unlink()
    spade_onnx(mine_onnx)
    code, err = run_main("spade.export", [f"ckpt_path={ckpt}", "latency_runs=0"])
    assert code == 2 and "pass overwrite=true to replace it" in one_error_line(err)
    validate_export_config(compose_config("export", [f"ckpt_path={ckpt}", "overwrite=true", "paths.output_dir=."]))


@pytest.fixture(scope="module")
def empty_store(tmp_path_factory: pytest.TempPathFactory) -> str:
    """An MLflow store without runs (every row of a report is missing: the report is quick to build)."""
    from mlflow import MlflowClient

    uri = f"sqlite:///{tmp_path_factory.mktemp('mlflow')}/mlflow.db"
    MlflowClient(tracking_uri=uri).search_experiments()  # creates the store's tables
    return uri


def test_report_checks_the_pages_it_writes_into_output_dir(tmp_path: Path, run_main, empty_store: str) -> None:
    """Issue 51: ``spade.report ... output_dir=DIR`` replaced a user's ``table1.md``. A page (or CSV or chart) in
    ``output_dir`` that SPADE did not write is refused before any run is read; one an earlier report wrote is
    replaced only with ``overwrite=true``; an empty ``output_dir`` is refused."""
    out = tmp_path / "reports"
    out.mkdir()
    for name in ("table1.md", "table1.csv", "table1.png"):
        user = out / name
        user.write_text(f"my own {name}")
        code, err = run_main("spade.report", ["table=table1", f"tracking_uri={empty_store}", f"output_dir={out}",
                                              "overwrite=true", "log_to_runs=false"])
        assert code == 2, err
        line = one_error_line(err)
        assert f"output_dir={out}: {user} exists and was not written by SPADE" in line
        assert user.read_text() == f"my own {name}"
        user.unlink()
    args = ["table=table1", f"tracking_uri={empty_store}", f"output_dir={out}", "log_to_runs=false"]
    code, err = run_main("spade.report", args)  # a fresh folder: written
    assert code == 0, err
    assert {p.name for p in out.iterdir()} >= {"table1.md", "table1.csv", "table1.png"}
    code, err = run_main("spade.report", args)  # its own pages: only with overwrite=true
    assert code == 2 and "pass overwrite=true to replace it" in one_error_line(err)
    code, err = run_main("spade.report", [*args, "overwrite=true"])
    assert code == 0, err
    code, err = run_main("spade.report", [*args[:2], "output_dir=''"])
    assert code == 2 and "output_dir='' is an empty path" in one_error_line(err)


def test_bench_checks_its_json_before_any_section(tmp_path: Path, run_main) -> None:
    """Issue 51: ``spade.bench ... out_json=FILE`` replaced a user's JSON. Refused before any section runs; an
    earlier benchmark's JSON is replaced only with ``overwrite=true``; ``out_json=''`` is refused."""
    mine = tmp_path / "results.json"
    mine.write_text('{"my": "numbers"}')
    for extra in ([], ["overwrite=true"]):
        code, err = run_main("spade.bench", ["quick=true", f"out_json={mine}", "sections=[decoder]", *extra])
        assert code == 2, err
        assert f"out_json={mine} exists and was not written by SPADE" in one_error_line(err)
    assert mine.read_text() == '{"my": "numbers"}'
    earlier = tmp_path / "bench.json"
    earlier.write_text(json.dumps({"mode": "quick", "machine": {}, "settings": {}}))
    code, err = run_main("spade.bench", ["quick=true", f"out_json={earlier}", "sections=[decoder]"])
    assert code == 2 and "pass overwrite=true to replace it" in one_error_line(err)
    code, err = run_main("spade.bench", ["quick=true", "out_json=''", "sections=[decoder]"])
    assert code == 2 and "out_json='' is an empty path" in one_error_line(err)


@pytest.mark.parametrize("override", ["paths.data_dir=''", "paths.log_dir=''", "paths.root_dir=/"])
def test_an_empty_or_root_path_is_refused_before_any_work(tmp_path: Path, run_main, override: str) -> None:
    """Issue 51: ``spade.train paths.data_dir=''`` trained and exited 0 after generating its datasets under
    ``/tiny/``. An empty (or root) ``paths.*`` folder is refused in one line, before any data is made."""
    existed = Path("/tiny").exists()
    code, err = run_main("spade.train", ["+experiment=t1_small_bc_L", "logger=none", override])
    assert code == 2, err
    key = override.split("=")[0]
    line = one_error_line(err)
    assert line.startswith(f"error: {key}=") and ("empty path" in line or "filesystem root" in line)
    assert Path("/tiny").exists() == existed
