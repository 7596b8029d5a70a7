"""Student export: ONNX / TorchScript files that reproduce PyTorch's logits and carry the window metadata."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch

from spade.deploy.export import ExportError, example_states, export_student, read_metadata
from spade.maps.frame import RobotFrame
from spade.models.builders import build_model
from spade.models.modelfile import INPUT_ENCODING, open_model
from factories import hand_made_checkpoint
from factories import PARITY_BOUND

REPO = Path(__file__).resolve().parents[1]


def robot_data(size: int = 32, resolution_m: float = 0.2) -> dict:
    """The ``data`` entry of a student trained on robot-frame windows of ``size`` px."""
    return {"image_size": [size, size], "resolution_m": resolution_m, "frame": RobotFrame.for_size(size).to_json(),
            "input_encoding": INPUT_ENCODING}


def test_onnx_export_of_a_fitted_student(tiny_checkpoints: dict[str, str], tmp_path: Path) -> None:
    ort = pytest.importorskip("onnxruntime")
    from spade.training.student_module import StudentModule

    report = export_student(tiny_checkpoints["student"], tmp_path / "student.onnx", "onnx", latency_runs=2,
                            latency_batches=(1, 2))
    assert report.out_path.is_file() and report.format == "onnx"
    assert 0.0 <= report.max_abs_diff < PARITY_BOUND
    assert set(report.latency_ms) == {"eager_b1", "onnxruntime_b1", "eager_b2", "onnxruntime_b2"}
    assert all(v > 0 for v in report.latency_ms.values())

    meta = read_metadata(report.out_path)
    assert meta == json.loads(json.dumps(report.metadata))
    assert meta["role"] == "student" and meta["config"]["preset"] == "medium" and meta["opset"] == 17
    assert meta["data"]["image_size"] == [64, 64] and meta["data"]["resolution_m"] == pytest.approx(0.1)
    assert meta["data"]["input_encoding"] == INPUT_ENCODING
    assert RobotFrame.from_json(meta["data"]["frame"]) == RobotFrame.for_size(64)  # the training windows' frame
    assert meta["source_checkpoint"] == str(Path(tiny_checkpoints["student"]).resolve())
    assert meta["torch_version"] == torch.__version__

    session = ort.InferenceSession(str(report.out_path), providers=["CPUExecutionProvider"])
    (inp,), (out,) = session.get_inputs(), session.get_outputs()
    assert inp.name == "state" and inp.type == "tensor(float)" and inp.shape[1:] == [3, 64, 64]
    assert isinstance(inp.shape[0], str)  # the dynamic batch axis
    assert out.name == "logits" and out.shape[1:] == [1, 64, 64]
    assert json.loads(session.get_modelmeta().custom_metadata_map["spade"]) == meta

    # Independently of export_student's own parity check: the LightningModule's forward on a batch of 3.
    module = StudentModule.load_from_checkpoint(tiny_checkpoints["student"], map_location="cpu").eval()
    state = example_states(3, (64, 64), seed=11)
    with torch.no_grad():
        expected = module(state).numpy()
    got = session.run(["logits"], {"state": state.numpy()})[0]
    assert got.shape == (3, 1, 64, 64)
    assert np.abs(got - expected).max() < PARITY_BOUND


@pytest.mark.filterwarnings("ignore::DeprecationWarning")  # torch.jit.load: TorchScript is deprecated in torch 2.x
def test_torchscript_export_carries_the_metadata(tmp_path: Path) -> None:
    data = robot_data()
    ckpt = hand_made_checkpoint(tmp_path / "s.ckpt", data=data)
    report = export_student(ckpt, None, "torchscript", latency_runs=0, parity_batch=3)
    assert report.out_path == tmp_path / "s.pt" and report.latency_ms == {}
    assert report.max_abs_diff < PARITY_BOUND
    extra = {"spade.json": ""}
    module = torch.jit.load(str(report.out_path), _extra_files=extra)
    assert json.loads(extra["spade.json"]) == read_metadata(report.out_path) == json.loads(json.dumps(report.metadata))
    written = dict(read_metadata(report.out_path)["data"])
    assert written.pop("footprint")["assumed"] is True  # the checkpoint records none: the export says it assumes one
    assert written == data
    state = example_states(2, (32, 32), seed=3)
    with torch.no_grad():
        assert module(state).shape == (2, 1, 32, 32)
    assert open_model(report.out_path)(state).shape == (2, 1, 32, 32)


def test_an_axis_aligned_student_is_refused_with_the_fix(tmp_path: Path) -> None:
    """Students trained before robot-frame windows (no ``data``, or ``data`` without a frame) are not exported:
    no planner could build their windows."""
    for name, data in (("none", None), ("axis", {"image_size": [32, 32], "resolution_m": 0.2})):
        ckpt = hand_made_checkpoint(tmp_path / f"{name}.ckpt", data=data)
        with pytest.raises(ExportError, match=f"{name}.ckpt.*axis-aligned.*[Rr]etrain"):
            export_student(ckpt, tmp_path / f"{name}.onnx", "onnx", latency_runs=0)
        assert not (tmp_path / f"{name}.onnx").exists()


def test_bad_inputs_are_refused_with_the_fix(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="spade.train"):
        export_student(tmp_path / "missing.ckpt")
    expert = hand_made_checkpoint(tmp_path / "expert.ckpt", role="expert")
    with pytest.raises(ExportError, match="not 'student'"):
        export_student(expert, tmp_path / "e.onnx")
    good = hand_made_checkpoint(tmp_path / "s.ckpt", data=robot_data())
    with pytest.raises(ExportError, match="format=onnx"):
        export_student(good, tmp_path / "s.tflite", "tflite")
    odd = {**robot_data(), "image_size": [30, 30], "frame": RobotFrame.for_size(30).to_json()}
    with pytest.raises(ExportError, match="multiple of 4"):
        export_student(hand_made_checkpoint(tmp_path / "odd.ckpt", data=odd), tmp_path / "odd.pt", "torchscript")


@pytest.mark.filterwarnings("ignore::DeprecationWarning")  # the legacy ONNX exporter, as spade.deploy.export uses
def test_read_metadata_refuses_files_that_are_not_spade_exports(tmp_path: Path) -> None:
    onnx = pytest.importorskip("onnx")
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(os.urandom(256))
    plain_zip = tmp_path / "plain.pt"
    with zipfile.ZipFile(plain_zip, "w") as archive:
        archive.writestr("plain/data.pkl", b"")
    foreign = tmp_path / "foreign.onnx"
    torch.onnx.export(torch.nn.Conv2d(3, 1, 1), (torch.zeros(1, 3, 8, 8),), str(foreign), dynamo=False)
    assert onnx.load(str(foreign)).graph.node  # a valid ONNX file, just not ours
    for path in (junk, plain_zip, foreign):
        with pytest.raises(ExportError, match="spade.export"):
            read_metadata(path)
    with pytest.raises(FileNotFoundError):
        read_metadata(tmp_path / "absent.onnx")


@pytest.mark.slow  # a python -m spade.export process; the export in-process: test_onnx_export_of_a_fitted_student
def test_the_command_line_exports_and_reports(tmp_path: Path) -> None:
    pytest.importorskip("onnxruntime")
    ckpt = hand_made_checkpoint(tmp_path / "s.ckpt", data=robot_data())
    env = {**os.environ, "SPADE_HOME": str(tmp_path / "home")}
    cmd = [sys.executable, "-m", "spade.export", f"ckpt_path={ckpt}", f"out_path={tmp_path / 'cli.onnx'}",
           "latency_runs=2", f"report_path={tmp_path / 'report.json'}"]
    proc = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "max |logit difference|" in proc.stdout and "onnxruntime_b1" in proc.stdout
    report = json.loads((tmp_path / "report.json").read_text())
    assert report["max_abs_diff"] < PARITY_BOUND and report["metadata"]["data"]["resolution_m"] == 0.2
    assert read_metadata(tmp_path / "cli.onnx")["role"] == "student"
