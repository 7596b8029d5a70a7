"""Reliability, third round: the wrong cases of the probe, reproduced, and the new behaviour.

- default output paths are checked as explicit ones are (``spade.export``'s export beside the checkpoint,
  ``spade.report``'s pages, ``spade.bench``'s JSON), and an empty path is refused instead of the filesystem root;
- a dataset manifest without its ``manifest_sha256`` is refused by ``verify`` and by loading;
- an ONNX graph carrying a copy of a real export's ``spade`` metadata is refused by the planner (torch and
  torch-free), ``spade.plan`` and the sketch server; an export from before the check is refused unless allowed
  (``allow_unsigned``, round 5).
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
    """A manifest whose resolution and generator record were edited and whose ``manifest_sha256`` was
    deleted verified "OK" and loaded. Now both refuse it, naming the file and the fix (regenerate)."""
    from spade.data import DatasetError
    from spade.data.path_dataset import PathDataset
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
    """``spade.export ckpt_path=DIR/student.ckpt`` replaced a user's own ``DIR/student.onnx`` (and with
    ``format=torchscript`` a text file ``student.pt``) and exited 0; a rerun replaced its own export without
    ``overwrite=true``. The default path is now checked as ``out_path=`` is, before any work."""
    from spade.config.export_checks import validate_export_config
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
    """``spade.report ... output_dir=DIR`` replaced a user's ``table1.md``. A page (or CSV or chart) in
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
    """``spade.bench ... out_json=FILE`` replaced a user's JSON. Refused before any section runs; an
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
    """``spade.train paths.data_dir=''`` trained and exited 0 after generating its datasets under
    ``/tiny/``. An empty (or root) ``paths.*`` folder is refused in one line, before any data is made."""
    existed = Path("/tiny").exists()
    code, err = run_main("spade.train", ["+experiment=t1_small_bc_L", "logger=none", override])
    assert code == 2, err
    key = override.split("=")[0]
    line = one_error_line(err)
    assert line.startswith(f"error: {key}=") and ("empty path" in line or "filesystem root" in line)
    assert Path("/tiny").exists() == existed


# -- 3. forged ONNX models --------------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def real_export(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A real ONNX export of an untrained small student (64 px robot-frame windows)."""
    pytest.importorskip("onnxruntime")
    from spade.deploy.export import export_student

    folder = tmp_path_factory.mktemp("export")
    return export_student(student_checkpoint(folder / "student.ckpt"), folder / "student.onnx", "onnx",
                          latency_runs=0).out_path


def _metadata(path: Path) -> dict:
    from spade.models.modelfile import read_metadata

    return read_metadata(path)


def one_node_graph(path: Path, metadata: dict, node: object, initializer: list) -> Path:
    """A forged model of the right shapes, (N, 3, 64, 64) -> (N, 1, 64, 64), of one ``node`` (reading ``state``,
    writing ``logits``) and its ``initializer`` tensors, with ``metadata`` as its ``spade`` entry."""
    onnx = pytest.importorskip("onnx")
    from onnx import TensorProto, helper

    graph = helper.make_graph([node], "forged",
                              [helper.make_tensor_value_info("state", TensorProto.FLOAT, ["N", 3, 64, 64])],
                              [helper.make_tensor_value_info("logits", TensorProto.FLOAT, ["N", 1, 64, 64])],
                              initializer=initializer)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    entry = model.metadata_props.add()
    entry.key, entry.value = "spade", json.dumps(metadata)
    onnx.save(model, str(path))
    return path


def conv_graph(path: Path, metadata: dict) -> Path:
    """A forged graph of the right shapes, (N, 3, 64, 64) -> (N, 1, 64, 64): one 1x1 convolution of its own."""
    pytest.importorskip("onnx")
    import numpy as np
    from onnx import helper, numpy_helper

    weight = numpy_helper.from_array(np.full((1, 3, 1, 1), 0.3, np.float32), "w")
    return one_node_graph(path, metadata, helper.make_node("Conv", ["state", "w"], ["logits"]), [weight])


def edited_copy(src: Path, dst: Path, *, metadata: dict | None = None, weight_delta: float = 0.0) -> Path:
    """``src`` with its ``spade`` metadata replaced and/or one weight changed by ``weight_delta``."""
    onnx = pytest.importorskip("onnx")
    from onnx import numpy_helper

    model = onnx.load(str(src))
    if metadata is not None:
        next(e for e in model.metadata_props if e.key == "spade").value = json.dumps(metadata)
    if weight_delta:
        init = max(model.graph.initializer, key=lambda t: len(t.raw_data))
        values = numpy_helper.to_array(init).copy()
        values.flat[0] += weight_delta
        init.CopyFrom(numpy_helper.from_array(values, init.name))
    onnx.save(model, str(dst))
    return dst


def test_a_forged_onnx_graph_is_refused_wherever_a_student_is_opened(real_export: Path, tmp_path: Path) -> None:
    """An ONNX Identity graph carrying a copy of a real export's ``spade`` metadata was accepted by the
    Planner (and ``spade.plan``, the sketch server). Now the graph must match the metadata: shapes, the weight
    digest recorded at export, the parity probe; a mismatch names the file and says it was not written by
    spade.export."""
    import warnings

    from spade.deploy.plan_result import PlannerConfigError
    from spade.deploy.student_planner import Planner
    from spade.models.modelfile import ModelFileError, open_model
    from spade.models.onnx_check import UncheckedExportWarning

    meta = _metadata(real_export)
    assert set(meta["integrity"]) == {"weights_sha256", "probe", "fields"} and meta["integrity"]["probe"]["seed"] == 0
    with warnings.catch_warnings():
        warnings.simplefilter("error", UncheckedExportWarning)
        assert open_model(real_export)(__import__("numpy").zeros((2, 3, 64, 64), "float32")).shape == (2, 1, 64, 64)
        Planner(real_export)  # the real export opens, unwarned

    forged = {
        "identity": spade_onnx(tmp_path / "identity.onnx", meta),  # the probe's case: shapes differ
        "conv": conv_graph(tmp_path / "conv.onnx", meta),  # right shapes, other weights
        "weights": edited_copy(real_export, tmp_path / "weights.onnx", weight_delta=0.5),  # one weight edited
    }
    reasons = {"identity": "its graph's output has shape", "conv": "its weights do not match",
               "weights": "its weights do not match"}
    for name, path in forged.items():
        with pytest.raises(ModelFileError, match="not the export its SPADE metadata describes") as info:
            open_model(path)
        message = str(info.value)
        assert str(path) in message and reasons[name] in message and "python -m spade.export" in message
        with pytest.raises(PlannerConfigError, match="was not written by python -m spade.export"):
            Planner(path)
    # the digest copied along with a forged graph's own weights: the probe tells them apart
    conv_meta = _metadata(forged["conv"])
    from spade.models.onnx_check import weights_sha256

    conv_meta["integrity"] = {**meta["integrity"], "weights_sha256": weights_sha256(forged["conv"].read_bytes())}
    probe_only = edited_copy(forged["conv"], tmp_path / "probe.onnx", metadata=conv_meta)
    with pytest.raises(ModelFileError, match="differs from the one recorded at export"):
        open_model(probe_only)


def test_an_export_from_before_the_check_opens_only_when_allowed(real_export: Path, tmp_path: Path) -> None:
    """Files exported before the digest and probe were recorded opened with a warning; since round 5 they are
    refused unless their user opts in (``allow_unsigned``), and then open with a warning that they are unchecked
    and how to re-export them; their shapes are still checked (an old-style forged Identity graph)."""
    from spade.models.modelfile import ModelFileError, open_model
    from spade.models.onnx_check import UncheckedExportWarning

    old_meta = {k: v for k, v in _metadata(real_export).items() if k != "integrity"}
    old = edited_copy(real_export, tmp_path / "old.onnx", metadata=old_meta)
    with pytest.raises(ModelFileError, match=r"old\.onnx carries no integrity record.*allow_unsigned=true"):
        open_model(old)
    with pytest.warns(UncheckedExportWarning, match=r"old\.onnx .*opened unchecked.*python -m spade\.export"):
        runner = open_model(old, allow_unsigned=True)
    assert runner.info == old_meta
    with pytest.raises(ModelFileError, match="its graph's output has shape"):
        open_model(spade_onnx(tmp_path / "old_identity.onnx", old_meta), allow_unsigned=True)


def test_spade_plan_and_the_sketch_server_refuse_a_forged_model(real_export: Path, tmp_path: Path,
                                                                run_main) -> None:
    """``spade.plan`` (exit 0 with 64 waypoints before) and the sketch server (``POST /api/model`` 200 before)."""
    from factories import site_map

    forged = spade_onnx(tmp_path / "forged.onnx", _metadata(real_export))
    yaml_path = site_map(tmp_path)
    code, err = run_main("spade.plan", [f"map={yaml_path}", "start=[0.0,1.0,0.0]", "goal=[2.0,1.0]",
                                        f"model_path={forged}", f"out={tmp_path / 'plan.png'}"])
    assert code == 2, err
    assert "not the export its SPADE metadata describes" in one_error_line(err) and str(forged) in err
    assert not (tmp_path / "plan.png").exists()

    pytest.importorskip("fastapi")
    pytest.importorskip("httpx")
    from fastapi.testclient import TestClient

    from spade.sketching import build_app
    from test_sketch_api import LOCAL, TINY

    client = TestClient(build_app(str(yaml_path), tmp_path / "sketches", TINY), base_url=LOCAL)
    r = client.post("/api/model", json={"path": str(forged)})
    assert r.status_code == 422 and "was not written by python -m spade.export" in r.json()["error"], r.text
    assert client.get("/api/model").json() == {"model": None}
    import shutil

    real = shutil.copy(real_export, tmp_path / "student.onnx")  # a real export in the model folders: loaded
    r = client.post("/api/model", json={"path": str(real)})
    assert r.status_code == 200, r.text


@pytest.mark.slow  # a subprocess without torch (the deploy install)
def test_the_torch_free_planner_refuses_a_forged_model(real_export: Path, tmp_path: Path) -> None:
    """The deploy install (onnxruntime alone, no torch, no onnx package) runs the same check."""
    from test_deploy_install import HIDE

    forged = spade_onnx(tmp_path / "forged.onnx", _metadata(real_export))
    script = HIDE + (
        "import sys, json\n"
        "from spade.planner import Planner\n"
        "Planner(sys.argv[1])\n"
        "try:\n"
        "    Planner(sys.argv[2])\n"
        "except Exception as err:\n"
        "    print(json.dumps({'error': str(err), 'torch': 'torch' in sys.modules}))\n")
    proc = subprocess.run([sys.executable, "-c", script, str(real_export), str(forged)], cwd=REPO,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert not out["torch"] and str(forged) in out["error"] and "not written by python -m spade.export" in out["error"]
