"""A model export is trusted only as far as it is signed: its integrity record covers its weights (a digest and a
parity probe) and every field a planner acts on; a forged graph, an edited field or a file without a record is
refused by the Planner (torch and torch-free), ``spade.plan``, the sketch app and the ROS node, unless its user
opts in to an unsigned file (``allow_unsigned``)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from factories import edited_copy, export_metadata, one_node_graph, spade_onnx, student_checkpoint
from refusal_support import one_error_line

REPO = Path(__file__).resolve().parents[1]


def conv_graph(path: Path, metadata: dict) -> Path:
    """A forged graph of the right shapes, (N, 3, 64, 64) -> (N, 1, 64, 64): one 1x1 convolution of its own."""
    pytest.importorskip("onnx")
    import numpy as np
    from onnx import helper, numpy_helper

    weight = numpy_helper.from_array(np.full((1, 3, 1, 1), 0.3, np.float32), "w")
    return one_node_graph(path, metadata, helper.make_node("Conv", ["state", "w"], ["logits"]), [weight])


def test_a_forged_onnx_graph_is_refused_wherever_a_student_is_opened(real_export: Path, tmp_path: Path) -> None:
    """An ONNX Identity graph carrying a copy of a real export's ``spade`` metadata was accepted by the
    Planner (and ``spade.plan``, the sketch server). Now the graph must match the metadata: shapes, the weight
    digest recorded at export, the parity probe; a mismatch names the file and says it was not written by
    spade.export."""
    import warnings

    from spade.deploy.student_planner import Planner, PlannerConfigError
    from spade.models.modelfile import ModelFileError, open_model
    from spade.models.onnx_check import UncheckedExportWarning

    meta = export_metadata(real_export)
    assert set(meta["integrity"]) == {"weights_sha256", "probe", "fields"} and meta["integrity"]["probe"]["seed"] == 0
    with warnings.catch_warnings():
        warnings.simplefilter("error", UncheckedExportWarning)
        assert open_model(real_export)(__import__("numpy").zeros((2, 3, 64, 64), "float32")).shape == (2, 1, 64, 64)
        Planner(real_export)  # the real export opens, unwarned

    forged = {
        "identity": spade_onnx(tmp_path / "identity.onnx", meta),  # shapes differ
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
    conv_meta = export_metadata(forged["conv"])
    from spade.models.onnx_check import weights_sha256

    conv_meta["integrity"] = {**meta["integrity"], "weights_sha256": weights_sha256(forged["conv"].read_bytes())}
    probe_only = edited_copy(forged["conv"], tmp_path / "probe.onnx", metadata=conv_meta)
    with pytest.raises(ModelFileError, match="differs from the one recorded at export"):
        open_model(probe_only)


def test_an_export_from_before_the_check_opens_only_when_allowed(real_export: Path, tmp_path: Path) -> None:
    """Files exported before the digest and probe were recorded opened with a warning; now they are
    refused unless their user opts in (``allow_unsigned``), and then open with a warning that they are unchecked
    and how to re-export them; their shapes are still checked (an old-style forged Identity graph)."""
    from spade.models.modelfile import ModelFileError, open_model
    from spade.models.onnx_check import UncheckedExportWarning

    old_meta = {k: v for k, v in export_metadata(real_export).items() if k != "integrity"}
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

    forged = spade_onnx(tmp_path / "forged.onnx", export_metadata(real_export))
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
    from factories import LOCAL, TINY

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
    from factories import HIDE

    forged = spade_onnx(tmp_path / "forged.onnx", export_metadata(real_export))
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


def occupancy_graph(path: Path, metadata: dict) -> Path:
    """A forged student: one node returning the occupancy channel, (N, 3, 64, 64) -> (N, 1, 64, 64), with
    ``metadata`` (a real export's, its integrity record left out) as its ``spade`` entry."""
    pytest.importorskip("onnx")
    from onnx import helper, numpy_helper

    consts = [numpy_helper.from_array(np.array([v], np.int64), n) for n, v in (("s", 0), ("e", 1), ("a", 1))]
    return one_node_graph(path, metadata, helper.make_node("Slice", ["state", "s", "e", "a"], ["logits"]), consts)


def test_a_model_without_an_integrity_record_is_refused_unless_allowed(real_export: Path, tmp_path: Path,
                                                                       run_main) -> None:
    """A one-node graph with a real export's metadata, its integrity record left out, planned everywhere
    with a warning that it "was exported before SPADE recorded a weight digest". Now it is refused by the Planner
    API and ``spade.plan``, saying what is missing and naming the opt-in; with ``allow_unsigned`` it opens, warned."""
    from factories import site_map
    from spade.deploy.student_planner import Planner, PlannerConfigError
    from spade.models.onnx_check import UncheckedExportWarning

    meta = {k: v for k, v in export_metadata(real_export).items() if k != "integrity"}
    forged = occupancy_graph(tmp_path / "forged.onnx", meta)
    with pytest.raises(PlannerConfigError) as info:
        Planner(forged)
    message = str(info.value)
    assert str(forged) in message and "carries no integrity record" in message and "allow_unsigned=true" in message
    assert "exported before" not in message  # not a guess about the file's age
    with pytest.warns(UncheckedExportWarning, match="opened unchecked"):
        Planner(forged, allow_unsigned=True)
    with pytest.raises(PlannerConfigError, match="allow_unsigned must be true or false"):
        Planner(forged, allow_unsigned="yes")

    yaml_path = site_map(tmp_path)
    query = [f"map={yaml_path}", "start=[0.0,1.0,0.0]", "goal=[2.0,1.0]", f"model_path={forged}"]
    code, err = run_main("spade.plan", [*query, f"out={tmp_path / 'plan.png'}"])
    assert code == 2 and "carries no integrity record" in one_error_line(err), err
    assert "planner.allow_unsigned=true" in err and not (tmp_path / "plan.png").exists()
    code, err = run_main("spade.plan", [*query, "planner.allow_unsigned=maybe"])
    assert code == 2 and "planner.allow_unsigned='maybe' is not a boolean" in one_error_line(err)
    code, err = run_main("spade.plan", [*query, "planner.allow_unsigned=true", f"out={tmp_path / 'unsigned.png'}"])
    assert code == 0, err
    assert (tmp_path / "unsigned.png").is_file()


def test_the_ros_node_takes_the_opt_in_from_its_planner_options(real_export: Path, tmp_path: Path) -> None:
    """The ROS node builds its planner from ``conf/ros.yaml``'s ``planner`` block: refused by default, opened with
    ``planner.allow_unsigned=true``."""
    from spade.deploy.student_planner import PlannerConfigError
    from spade.models.onnx_check import UncheckedExportWarning
    from spade.ros.launch import build_planner
    from spade.utils.config import compose_config

    meta = {k: v for k, v in export_metadata(real_export).items() if k != "integrity"}
    forged = occupancy_graph(tmp_path / "forged.onnx", meta)
    with pytest.raises(PlannerConfigError, match="carries no integrity record"):
        build_planner(compose_config("ros", [f"model_path={forged}", "paths.output_dir=."]))
    with pytest.warns(UncheckedExportWarning):
        build_planner(compose_config("ros", [f"model_path={forged}", "planner.allow_unsigned=true",
                                             "paths.output_dir=."]))


@pytest.mark.parametrize("field, value", [("resolution_m", 0.05),
                                          ("footprint", {"radius_m": 0.5, "inflation_radius_m": 0.55}),
                                          ("marker_encoding", "gaussian"), ("margin_m", 0.0), ("frame", None)])
def test_an_edited_field_of_a_real_export_is_refused_by_name(real_export: Path, tmp_path: Path, field: str,
                                                             value: object) -> None:
    """Editing ``resolution_m`` 0.1 -> 0.05 (every plan rescaled) or the footprint to 0.5 m (a student of
    a 0.105 m robot planning for a 0.5 m one) was trusted. Now every field a planner acts on is in the record, and
    an edit is refused naming the field; so is one added since export."""
    from spade.deploy.student_planner import Planner, PlannerConfigError
    from spade.models.modelfile import ModelFileError, open_model

    meta = export_metadata(real_export)
    if value is None:
        del meta["data"][field]
    else:
        meta["data"][field] = value
    edited = edited_copy(real_export, tmp_path / "edited.onnx", metadata=meta)
    with pytest.raises(ModelFileError) as info:
        open_model(edited)
    assert f"data.{field}" in str(info.value) and "edited" in str(info.value) and str(edited) in str(info.value)
    with pytest.raises(PlannerConfigError, match=f"data\\.{field}"):
        Planner(edited, allow_unsigned=True)  # the opt-in is for files without a record, not for edited ones
    meta = export_metadata(real_export)
    meta["data"]["extra_scale"] = 2.0
    with pytest.raises(ModelFileError, match=r"data\.extra_scale .*was not in its metadata at export"):
        open_model(edited_copy(real_export, tmp_path / "added.onnx", metadata=meta))


def test_a_torchscript_export_is_signed_alike(tmp_path: Path) -> None:
    """TorchScript exports carry the same record (their weight digest over the archive's code and tensors): an
    edited field, or a file without the record, is refused as an ONNX one is."""
    import zipfile

    from spade.deploy.export import export_student
    from spade.models.modelfile import ModelFileError, open_model

    out = export_student(student_checkpoint(tmp_path / "s.ckpt"), tmp_path / "s.pt", "torchscript",
                         latency_runs=0).out_path
    meta = open_model(out).info
    assert set(meta["integrity"]) == {"weights_sha256", "probe", "fields"}

    def resaved(name: str, metadata: dict) -> Path:
        """``out`` with its ``spade.json`` replaced, every other entry as it was."""
        path = tmp_path / name
        with zipfile.ZipFile(out) as src, zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as dst:
            for item in src.infolist():
                body = json.dumps(metadata).encode() if item.filename.endswith("/extra/spade.json") else src.read(item)
                dst.writestr(item.filename, body)
        return path

    assert open_model(resaved("same.pt", meta)).info == meta  # re-written as it was: still the export
    edited = json.loads(json.dumps(meta))
    edited["data"]["resolution_m"] = 0.05
    with pytest.raises(ModelFileError, match=r"data\.resolution_m \(= 0\.05\) is not the value signed at export"):
        open_model(resaved("edited.pt", edited))
    with pytest.raises(ModelFileError, match="carries no integrity record"):
        open_model(resaved("unsigned.pt", {k: v for k, v in meta.items() if k != "integrity"}))


def test_an_older_record_of_the_weights_opens_only_if_its_window_matches(real_export: Path, tmp_path: Path) -> None:
    """An export from before the field digests (weights and probe only) still opens, with a warning naming what its
    record does not cover; one whose window disagrees with the one its probe was recorded on is refused."""
    from spade.models.modelfile import ModelFileError, open_model
    from spade.models.onnx_check import UncheckedExportWarning

    meta = export_metadata(real_export)
    meta["integrity"] = {k: v for k, v in meta["integrity"].items() if k != "fields"}
    older = edited_copy(real_export, tmp_path / "older.onnx", metadata=meta)
    with pytest.warns(UncheckedExportWarning, match=r"covers its weights and window size but not .*data\.resolution_m"):
        open_model(older)
    meta["data"]["image_size"] = [32, 32]
    with pytest.raises(ModelFileError, match=r"data\.image_size .* is not the \[64, 64\] window .*python -m spade\.export"):
        open_model(edited_copy(real_export, tmp_path / "older_edited.onnx", metadata=meta))


def test_the_sketch_app_refuses_an_unsigned_model_unless_allowed(real_export: Path, tmp_path: Path,
                                                                 run_main) -> None:
    """A model export without an integrity record given to ``spade.sketch`` at start-up: refused in one line naming
    the sketch app's own opt-in (``allow_unsigned=true``); with it, the app opens the model, warned."""

    from factories import site_map
    from spade.models.onnx_check import UncheckedExportWarning
    from spade.sketching import build_app

    meta = {k: v for k, v in export_metadata(real_export).items() if k != "integrity"}
    forged = occupancy_graph(tmp_path / "forged.onnx", meta)
    yaml_path = site_map(tmp_path)
    base = [f"map={yaml_path}", f"out_dir={tmp_path / 'sk'}", f"model_path={forged}"]
    code, err = run_main("spade.sketch", base)
    assert code == 2, err
    line = one_error_line(err)
    assert "carries no integrity record" in line and "spade.sketch: allow_unsigned=true" in line, line
    code, err = run_main("spade.sketch", [*base, "allow_unsigned=maybe"])
    assert code == 2 and "allow_unsigned='maybe' is not a boolean" in one_error_line(err), err
    with pytest.warns(UncheckedExportWarning, match="opened unchecked"):
        build_app(str(yaml_path), tmp_path / "sk", model=forged, allow_unsigned=True)
