"""Reliability, fifth round (issue 63): the wrong cases of the probe, reproduced, and the new behaviour.

- a model export is trusted only as far as it is signed: its integrity record covers every field a planner acts
  on (window, resolution, markers, footprint, ...) as well as its weights; a file without a record is refused
  unless its user opts in (``allow_unsigned``); an edited field is refused, named;
- ``spade.data.verify`` refuses non-finite or absurd poses, waypoints and alternatives with the loaders' check;
- ``spade.closed_loop`` keys a finished drive by its full settings: a changed setting reruns it.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from test_reliability_outputs import one_error_line, run_main, student_checkpoint  # noqa: F401 - a fixture
from test_reliability_round3 import _metadata, edited_copy, one_node_graph, real_export  # noqa: F401 - a fixture

REPO = Path(__file__).resolve().parents[1]


# -- 1. model files trusted only as far as they are signed -----------------------------------------------------------
def occupancy_graph(path: Path, metadata: dict) -> Path:
    """The probe's forged student: one node returning the occupancy channel, (N, 3, 64, 64) -> (N, 1, 64, 64), with
    ``metadata`` (a real export's, its integrity record left out) as its ``spade`` entry."""
    pytest.importorskip("onnx")
    from onnx import helper, numpy_helper

    consts = [numpy_helper.from_array(np.array([v], np.int64), n) for n, v in (("s", 0), ("e", 1), ("a", 1))]
    return one_node_graph(path, metadata, helper.make_node("Slice", ["state", "s", "e", "a"], ["logits"]), consts)


def test_a_model_without_an_integrity_record_is_refused_unless_allowed(real_export: Path, tmp_path: Path,
                                                                       run_main) -> None:
    """Wrong 1: a one-node graph with a real export's metadata, its integrity record left out, planned everywhere
    with a warning that it "was exported before SPADE recorded a weight digest". Now it is refused by the Planner
    API and ``spade.plan``, saying what is missing and naming the opt-in; with ``allow_unsigned`` it opens, warned."""
    from factories import site_map
    from spade.deploy.plan_result import PlannerConfigError
    from spade.deploy.student_planner import Planner
    from spade.models.onnx_check import UncheckedExportWarning

    meta = {k: v for k, v in _metadata(real_export).items() if k != "integrity"}
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
    from spade.deploy.plan_result import PlannerConfigError
    from spade.models.onnx_check import UncheckedExportWarning
    from spade.ros.launch import build_planner
    from spade.utils.config import compose_config

    meta = {k: v for k, v in _metadata(real_export).items() if k != "integrity"}
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
    """Wrong 2: editing ``resolution_m`` 0.1 -> 0.05 (every plan rescaled) or the footprint to 0.5 m (a student of
    a 0.105 m robot planning for a 0.5 m one) was trusted. Now every field a planner acts on is in the record, and
    an edit is refused naming the field; so is one added since export."""
    from spade.deploy.plan_result import PlannerConfigError
    from spade.deploy.student_planner import Planner
    from spade.models.modelfile import ModelFileError, open_model

    meta = _metadata(real_export)
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
    meta = _metadata(real_export)
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

    meta = _metadata(real_export)
    meta["integrity"] = {k: v for k, v in meta["integrity"].items() if k != "fields"}
    older = edited_copy(real_export, tmp_path / "older.onnx", metadata=meta)
    with pytest.warns(UncheckedExportWarning, match=r"covers its weights and window size but not .*data\.resolution_m"):
        open_model(older)
    meta["data"]["image_size"] = [32, 32]
    with pytest.raises(ModelFileError, match=r"data\.image_size .* is not the \[64, 64\] window .*python -m spade\.export"):
        open_model(edited_copy(real_export, tmp_path / "older_edited.onnx", metadata=meta))


# -- 2. poses, waypoints and alternatives: one value check for verify and every loader --------------------------------
def poisoned(root: Path, name: str, value: float, rows: slice = slice(None), column: int = 0, n: int = 6) -> Path:
    """A synthetic dataset whose ``name`` array holds ``value`` at ``rows`` (column ``column``), its checksums and
    manifest checksum recomputed: only the value checks can refuse it."""
    import hashlib

    from factories import write_synthetic
    from spade.data.format import MANIFEST_CHECKSUM, manifest_checksum

    write_synthetic(root, n=n)
    path = root / f"{name}.bin"
    values = np.fromfile(path, dtype="<f4").reshape(n, -1)
    values[rows, column] = value
    values.tofile(path)
    manifest = json.loads((root / "manifest.json").read_text())
    manifest["files"][name]["sha256"] = hashlib.sha256(path.read_bytes()).hexdigest()
    manifest[MANIFEST_CHECKSUM] = manifest_checksum(manifest)
    (root / "manifest.json").write_text(json.dumps(manifest))
    return path


@pytest.mark.parametrize("name, value, column, says", [
    ("pose", np.nan, 0, "holds NaN or inf"),  # wrong 3: every pose NaN
    ("pose", np.inf, 2, "holds NaN or inf"),
    ("pose", 1e30, 1, "a pose beyond 1e+06 m"),
    ("pose", 5000.0, 2, "a yaw beyond 1000 rad"),
    ("waypoints", 1e30, 0, "window pixel coordinates beyond 3200"),  # unclear: finite absurd data failing late
])
def test_verify_and_the_loaders_refuse_the_same_absurd_values(tmp_path: Path, name: str, value: float, column: int,
                                                               says: str) -> None:
    """Wrong 3: ``spade.data.verify`` reported OK for a dataset whose every pose is NaN (``spade.evaluate`` refused
    it); finite absurd waypoints (1e30) failed late in evaluation and training. Now one check (value_problems)
    refuses them in both, with the same line naming the file, the first instance and the fix."""
    from spade.data import DatasetError
    from spade.data.path_dataset import PathDataset
    from spade.data.verify import verify

    path = poisoned(tmp_path / "ds", name, value, column=column)
    problems = verify(tmp_path / "ds")
    assert problems and str(path) in problems[0] and says in problems[0] and "Re-generate the dataset" in problems[0]
    with pytest.raises(DatasetError) as info:
        PathDataset(tmp_path / "ds")
    assert str(info.value) == problems[0]  # the same check, the same line


def test_verify_command_refuses_nan_poses_in_one_list(tmp_path: Path, capsys) -> None:
    """``python -m spade.data.verify`` (its main) exits 1 with the problem, no "OK"; a sound dataset is still OK."""
    from factories import write_synthetic
    from spade.data.verify import main

    poisoned(tmp_path / "ds", "pose", np.nan)
    assert main([str(tmp_path / "ds")]) == 1
    out = capsys.readouterr().out
    assert "OK" not in out and "pose.bin: instance 0 holds NaN or inf (6 instance(s) in all)" in out
    write_synthetic(tmp_path / "sound", n=4)
    assert main([str(tmp_path / "sound")]) == 0 and "OK" in capsys.readouterr().out


# -- 3. a closed-loop drive keyed by its full settings ----------------------------------------------------------------
def test_a_changed_condition_reruns_its_drives_and_the_page_drops_the_old_numbers(tmp_path: Path,
                                                                                  monkeypatch) -> None:
    """Wrong 4: drives were matched by name and source run only, and recorded no noise or offset: a changed
    perturbation printed "0 drives run" and the page kept the old numbers under "perturbed". Now each drive is
    keyed by its full settings (recorded with it): a changed setting reruns exactly the drives it changes, and the
    page shows each cell's latest settings only. The drive itself (spade.evaluate) is replaced by a stand-in that
    records a finished run with the tags it is given."""
    from types import SimpleNamespace

    from mlflow import MlflowClient

    import spade.experiments.closed_loop_table as table
    import spade.experiments.evaluation as evaluation
    from spade.utils.config import compose_config

    uri = f"sqlite:///{tmp_path}/mlflow.db"
    client = MlflowClient(tracking_uri=uri)
    experiment = client.create_experiment(table.CLOSED_LOOP_TABLE)
    driven: list[dict] = []

    def drive(cfg) -> dict:  # noqa: ANN001 - spade.evaluate's stand-in
        noise = float(cfg.drive.noise_xy_m)
        tags = {k: str(v) for k, v in cfg.tags.items()}
        run = client.create_run(experiment, run_name=str(cfg.run_name), tags=tags)
        client.log_param(run.info.run_id, "cfg/seed", int(cfg.seed))
        client.log_metric(run.info.run_id, "closed_loop/ape_cm", 100.0 * noise + 1.0)
        client.log_metric(run.info.run_id, "closed_loop/success_rate", 1.0)
        client.set_terminated(run.info.run_id, "FINISHED")
        driven.append({"condition": tags["condition"], "noise": noise, "settings": json.loads(tags["drive_settings"])})
        return {"closed_loop/success_rate": 1.0, "closed_loop/ape_cm": 100.0 * noise + 1.0}

    source = SimpleNamespace(info=SimpleNamespace(run_id="source-run-1"), data=SimpleNamespace(params={"cfg/seed": "0"}))
    monkeypatch.setattr(evaluation, "evaluate", drive)
    monkeypatch.setattr(table, "source_runs", lambda *args: [source])
    monkeypatch.setattr(table, "_best_checkpoint", lambda *args: tmp_path / "best.ckpt")

    def launch(noise: float) -> list[dict]:
        from omegaconf import OmegaConf

        cfg = compose_config("closed_loop", [f"tracking_uri={uri}", f"paths.output_dir={tmp_path}/out"])
        cfg.sources = [{"table": "guidance", "row": "bc"}]
        cfg.datasets = {"heldout": {"data": "lshape", "scenarios": 3}}
        cfg.conditions = OmegaConf.create({"clean": {}, "perturbed": {"noise_xy_m": noise}})
        return table.launch(cfg)

    assert [r["run"] for r in launch(0.03)] == ["bc__heldout__clean", "bc__heldout__perturbed"]
    assert driven[-1]["settings"]["drive"]["noise_xy_m"] == 0.03  # the settings are recorded with the drive
    assert launch(0.03) == []  # the same settings: nothing to run
    assert [r["run"] for r in launch(0.1)] == ["bc__heldout__perturbed"]  # the changed condition alone reruns
    assert driven[-1]["noise"] == 0.1
    cells = table.fetch_drives(uri)
    assert cells[("bc", "heldout", "perturbed")].values("closed_loop/ape_cm") == [pytest.approx(11.0)]
    assert cells[("bc", "heldout", "clean")].values("closed_loop/ape_cm") == [pytest.approx(1.0)]
    # a second seed driven under the earlier settings, finishing last: its settings are now the cell's latest, and
    # the cell shows the drives of those settings alone (both seeds at 0.03), never the 0.1 drive beside them
    old = next(r for r in client.search_runs([experiment], "attributes.run_name = 'bc__heldout__perturbed'")
               if r.data.tags["drive_settings"] and json.loads(r.data.tags["drive_settings"])["drive"]["noise_xy_m"] == 0.03)
    late = client.create_run(experiment, run_name="bc__heldout__perturbed", tags=old.data.tags)
    client.log_param(late.info.run_id, "cfg/seed", 1)
    client.log_metric(late.info.run_id, "closed_loop/ape_cm", 4.0)
    client.set_terminated(late.info.run_id, "FINISHED")
    assert table.fetch_drives(uri)[("bc", "heldout", "perturbed")].values("closed_loop/ape_cm") == [4.0, 4.0]


# -- 4. spade.closed_loop and drive.* checked before any run opens ----------------------------------------------------
@pytest.mark.parametrize("override, says", [
    ("drive.scenarios=0", "drive.scenarios=0 is out of range"),
    ("drive.baselines=shortest", "drive.baselines='shortest' is not a list of ['shortest', 'heading']"),
    ("drive.commit_tol_cm=-1", "drive.commit_tol_cm=-1 is out of range"),
    ("drive.mcap_episodes=-3", "drive.mcap_episodes=-3 is out of range"),
    ("drive.follower.speed_mps=0", "drive.follower.speed_mps=0 is out of range"),
    ("drive.noise_xy_m=abc", "drive.noise_xy_m='abc' is not a number"),
])
def test_drive_options_are_checked_before_the_evaluation(override: str, says: str) -> None:
    """Unclear: ``drive.*`` options were checked after the MLflow run opened (a FAILED run left) or not at all
    (``scenarios=0``, ``baselines=shortest`` read as the letter "s", a negative ``commit_tol_cm``,
    ``mcap_episodes=-3``). Now ``spade.evaluate``'s config check refuses each in one line, before the checkpoint is
    even read."""
    from spade.config.drive_checks import check_drive_config
    from spade.utils.config import compose_config
    from spade.utils.errors import ConfigError

    cfg = compose_config("evaluate", ["closed_loop=true", override])
    with pytest.raises(ConfigError) as info:
        check_drive_config(cfg)
    assert says in str(info.value) and "; " in str(info.value)
    check_drive_config(compose_config("evaluate", ["closed_loop=true"]))  # the defaults pass


def test_evaluate_with_nothing_to_evaluate_is_refused_in_one_line(tmp_path: Path, run_main) -> None:
    """``open_loop=false closed_loop=false`` was accepted; it is one line and exit 2 now, and no store is made."""
    ckpt = student_checkpoint(tmp_path / "s.ckpt")
    store = tmp_path / "mlflow.db"
    code, err = run_main("spade.evaluate", [f"ckpt_path={ckpt}", "open_loop=false", "closed_loop=false",
                                            f"paths.mlflow_tracking_uri=sqlite:///{store}"])
    assert code == 2 and "leaves nothing to evaluate" in one_error_line(err)
    assert not store.exists()
    code, err = run_main("spade.evaluate", [f"ckpt_path={ckpt}", "closed_loop=true", "drive.scenarios=0",
                                            f"paths.mlflow_tracking_uri=sqlite:///{store}"])
    assert code == 2 and "drive.scenarios=0 is out of range" in one_error_line(err) and not store.exists()


@pytest.mark.parametrize("override, says", [
    ("sources=[{table: guidance}]", "sources[0]="),
    ("sources=[{table: guidance, row: \"a'b\"}]", "sources[0].row=\"a'b\" is not a row name"),
    ("sources=guidance", "sources='guidance' is not a non-empty list"),
    ("datasets.heldout.scenarios=0", "datasets.heldout.scenarios=0 is out of range"),
    ("conditions.perturbed.noise_xy_m=-0.1", "conditions.perturbed.noise_xy_m=-0.1 is out of range"),
    ("+conditions.perturbed.nois_xy_m=0.1", "conditions.perturbed.nois_xy_m: no such drive setting"),
    ("+conditions.odd.baselines=shortest", "conditions.odd.baselines='shortest' is not a list"),
])
def test_closed_loop_is_checked_before_any_drive(tmp_path: Path, run_main, override: str, says: str) -> None:
    """Unclear: ``spade.closed_loop`` had no preflight: malformed ``sources``, a quote in a row name, a bad
    condition gave tracebacks or exit 0. Now one line and exit 2, before any store is opened."""
    store = tmp_path / "mlflow.db"
    code, err = run_main("spade.closed_loop", [override, f"tracking_uri=sqlite:///{store}"])
    assert code == 2, err
    assert says in one_error_line(err)
    assert not store.exists()
