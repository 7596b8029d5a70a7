"""Reliability and safety of every entry point: nothing of the user's is ever overwritten, every entry
point checks its config and inputs first and fails with one ``error: ...; <fix>`` line and exit status 2, runs end
in the state they are in, prerequisites fetched from the registry are checked like explicit paths.

The entry points run in this process (their Hydra ``main`` with a patched ``sys.argv``), which is what
``python -m spade.X`` runs after its argument shorthands; the tests that start processes or train are in
``test_reliability_processes.py`` (marked slow).
"""

from __future__ import annotations

import errno
import hashlib
import runpy
import sys
from pathlib import Path

import numpy as np
import pytest
from hydra.core.global_hydra import GlobalHydra
from omegaconf import open_dict

from spade.data import DatasetWriter
from spade.data.path_dataset import PathDataset
from spade.config.preflight import validate_train_config
from spade.utils.errors import ConfigError

from factories import site_map, synthetic_instance
from training_helpers import compose_row

ROW = "t1_small_bc_L"
FID = "metrics.fid_extractor=randconv"  # the offline extractor whose weights are generated, not shipped


# -- helpers --------------------------------------------------------------------------------------------------------
def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def tree(root: Path) -> dict[str, str]:
    """Every file under ``root`` with its hash: what must come out of a refused command unchanged."""
    return {str(p.relative_to(root)): digest(p) for p in sorted(root.rglob("*")) if p.is_file()}


def student_checkpoint(path: Path, role: str = "student", size: int = 64) -> Path:
    """A checkpoint as spade.train writes it (an untrained small student), without training."""
    import torch

    from spade.maps.frame import RobotFrame
    from spade.models.builders import build_model

    net = build_model("student", "small")
    info = {"role": role, "config": dict(net.config),
            "data": {"image_size": [size, size], "resolution_m": 0.1, "frame": RobotFrame.for_size(size).to_json()}}
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save({"spade": info, "state_dict": {f"net.{k}": v for k, v in net.state_dict().items()}}, path)
    return path


def map_image(yaml_path: Path) -> Path:
    from spade.maps.ros_io import read_map_yaml

    return Path(read_map_yaml(yaml_path).image_path)


@pytest.fixture
def run_main(monkeypatch, tmp_path: Path, capsys):
    """``run_main("spade.plan", [...])`` -> (exit status, stderr): the entry point's Hydra main in this process."""
    monkeypatch.delenv("HYDRA_FULL_ERROR", raising=False)
    monkeypatch.setenv("SPADE_HOME", str(tmp_path / "home"))
    monkeypatch.setenv("OMP_WAIT_POLICY", "PASSIVE")  # what spade.train sets as a command (undone after the test)

    def run(module: str, args: list[str], hydra: bool = True) -> tuple[int, str]:
        GlobalHydra.instance().clear()
        extra = [f"hydra.run.dir={tmp_path / 'hydra'}"] if hydra else []
        monkeypatch.setattr(sys, "argv", [module, *args, *extra])
        capsys.readouterr()
        code = 0
        try:  # as python -m runs it (Hydra finds conf/ from the module's file when it runs as __main__)
            runpy.run_module(module, run_name="__main__", alter_sys=True)
        except SystemExit as exc:
            code = exc.code
        finally:
            GlobalHydra.instance().clear()
        return int(code or 0), capsys.readouterr().err

    return run


def one_error_line(err: str) -> str:
    """The single ``error:`` line a refused command prints (and nothing that looks like a traceback)."""
    assert "Traceback" not in err, err
    lines = [line for line in err.splitlines() if line.strip()]
    errors = [line for line in lines if line.startswith("error: ")]
    assert len(errors) == 1, err
    assert "; " in errors[0], errors[0]  # "<what is wrong>; <the fix>"
    return errors[0]


# -- 1. annotate overwrite=true never deletes what is not a dataset ---------------------------------------------------
def test_annotate_overwrite_refuses_a_folder_or_file_that_is_not_a_dataset(tmp_path: Path, run_main) -> None:
    """Case 1: ``overwrite=true out_dir=X`` deleted whatever X held (datasets, notes, a plain file), exit 0."""
    folder = tmp_path / "mine"
    (folder / "old_dataset").mkdir(parents=True)
    (folder / "old_dataset" / "notes.txt").write_text("two weeks of sketches")
    (folder / "notes.txt").write_text("do not delete")
    plain = tmp_path / "report.txt"
    plain.write_text("a plain file")
    before, plain_before = tree(folder), digest(plain)
    for out in (folder, plain):
        code, err = run_main("spade.annotate", ["overwrite=true", f"out_dir={out}", "num_instances=5",
                                                "maps=[warehouse:1]", "progress=false"])
        assert code == 2, err
        assert "never" in one_error_line(err) and str(out) in err
    assert tree(folder) == before and digest(plain) == plain_before
    # the writer itself refuses too (the data module and the sketching app write through it)
    from spade.data.writer import DatasetExistsError

    for out in (folder, plain):
        with pytest.raises(DatasetExistsError, match="never"):
            DatasetWriter(out, image_size=32, resolution=0.05, num_waypoints=16, overwrite=True)
    assert tree(folder) == before


def test_annotate_overwrite_replaces_only_a_spade_dataset_and_nothing_added_to_it(tmp_path: Path, run_main) -> None:
    """A web app's folder holding a ``manifest.json`` (and ``important.txt``) was deleted by ``annotate
    overwrite=true``, as was a user's ``NOTES.md`` inside a real dataset. Both are refused in one line naming what
    is kept; a dataset that holds only its own files is still replaced."""
    from factories import write_synthetic

    webapp = tmp_path / "webapp"
    webapp.mkdir()
    (webapp / "manifest.json").write_text('{"name": "my app", "start_url": "/"}')
    (webapp / "important.txt").write_text("keep me")
    dataset = tmp_path / "dataset"
    write_synthetic(dataset, n=3)
    (dataset / "NOTES.md").write_text("where these demonstrations come from")
    args = ["overwrite=true", "num_instances=5", "maps=[warehouse:1]", "progress=false"]
    for out, expected in ((webapp, "not a SPADE dataset's"), (dataset, "NOTES.md")):
        before = tree(out)
        code, err = run_main("spade.annotate", [*args, f"out_dir={out}"])
        assert code == 2, err
        line = one_error_line(err)
        assert expected in line and str(out) in line
        assert tree(out) == before
    (dataset / "NOTES.md").unlink()
    with DatasetWriter(dataset, image_size=32, resolution=0.05, num_waypoints=16, overwrite=True) as w:
        w.add(**synthetic_instance(np.random.default_rng(0), 32, 16), shape="L", map_id="m", scenario_id="m/0")
    assert len(PathDataset(dataset)) == 1


# -- 2. export never writes onto its checkpoint -----------------------------------------------------------------------
def test_export_never_writes_onto_its_checkpoint(tmp_path: Path, run_main) -> None:
    """Case 2: ``ckpt_path=s.pt format=torchscript`` (or ``out_path`` = ``ckpt_path``) overwrote the checkpoint."""
    ckpt = student_checkpoint(tmp_path / "s.pt")
    before = digest(ckpt)
    for args in (["format=torchscript"], [f"out_path={ckpt}", "format=torchscript"], [f"out_path={ckpt}"]):
        code, err = run_main("spade.export", [f"ckpt_path={ckpt}", "latency_runs=0", *args])
        assert code == 2, err
        line = one_error_line(err)
        assert "out_path" in line and ("overwrite" in line or "onto the checkpoint" in line or "end with" in line)
        assert digest(ckpt) == before
    from spade.deploy.export import ExportError, export_student

    with pytest.raises(ExportError, match="overwrite the checkpoint"):  # the library call refuses as well
        export_student(ckpt, None, "torchscript", latency_runs=0)
    assert digest(ckpt) == before


# -- 3. plan never writes onto its map or model ------------------------------------------------------------------------
def test_plan_never_writes_onto_its_map_or_model(tmp_path: Path, run_main) -> None:
    """Case 3: ``out=<the map's own image>`` overwrote the map; the next plan on it failed."""
    yaml_path = site_map(tmp_path)
    image = map_image(yaml_path)
    model = student_checkpoint(tmp_path / "student.ckpt")
    before = {p: digest(p) for p in (yaml_path, image, model)}
    for out in (image, yaml_path, model):
        code, err = run_main("spade.plan", [f"map={yaml_path}", "start=[0.0,1.0,0.0]", "goal=[2.0,1.0]",
                                            f"model_path={model}", f"out={out}"])
        assert code == 2, err
        assert "overwrite" in one_error_line(err) or "must end with .png" in err
    assert {p: digest(p) for p in before} == before


def test_plan_and_export_replace_only_their_own_files_and_only_when_asked(tmp_path: Path, run_main) -> None:
    """``plan out=`` replaced an existing picture and ``export out_path=`` an existing file, with no flag
    and no warning. A file SPADE did not write is refused whatever ``overwrite`` says; one it wrote (a plan picture
    carries SPADE's PNG marker) is replaced only with ``overwrite=true``."""
    from PIL import Image

    from spade.deploy.outputs import save_png, written_by_spade

    yaml_path = site_map(tmp_path)
    model = student_checkpoint(tmp_path / "student.ckpt")
    holiday = tmp_path / "holiday.png"
    Image.new("RGB", (8, 8), "red").save(holiday)
    ours = save_png(Image.new("RGB", (8, 8), "blue"), tmp_path / "plan.png")
    assert written_by_spade(ours) and not written_by_spade(holiday)
    foreign_export = tmp_path / "notes.onnx"
    foreign_export.write_text("my notes, not a model")
    before = {p: digest(p) for p in (holiday, ours, foreign_export)}
    query = [f"map={yaml_path}", "start=[0.0,1.0,0.0]", "goal=[2.0,1.0]", f"model_path={model}"]
    cases = [("spade.plan", [*query, f"out={holiday}", "overwrite=true"], "was not written by SPADE"),
             ("spade.plan", [*query, f"out={ours}"], "pass overwrite=true"),
             ("spade.plan", [*query, f"out={ours}", "overwrite=maybe"], "is not a boolean"),
             ("spade.export", [f"ckpt_path={model}", f"out_path={foreign_export}", "overwrite=true"],
              "was not written by SPADE")]
    for module, args, expected in cases:
        code, err = run_main(module, args)
        assert code == 2, err
        assert expected in one_error_line(err), err
    assert {p: digest(p) for p in before} == before
    from spade.config.plan_checks import validate_plan_config
    from spade.utils.config import compose_config

    validate_plan_config(compose_config("plan", [*query, f"out={ours}", "overwrite=true"]))  # its own: replaced


# -- 6. a full disk leaves nothing behind and says how much is needed --------------------------------------------------
def test_disk_full_removes_the_partial_folder_and_names_path_and_space(tmp_path: Path) -> None:
    """Case 6: ENOSPC while writing, then again in ``close()``, left a ``.partial`` folder and an error that named
    no folder."""
    from spade.data import DatasetError
    from spade.data.writer import DiskFullError

    class FullDisk:
        """A file on a disk that fills after ``room`` bytes (and fails again when closed, as a full disk does)."""

        def __init__(self, handle, room: int) -> None:
            self.handle, self.room = handle, room

        def write(self, data: bytes) -> int:
            if len(data) > self.room:
                raise OSError(errno.ENOSPC, "No space left on device")
            self.room -= len(data)
            return self.handle.write(data)

        def flush(self) -> None:
            raise OSError(errno.ENOSPC, "No space left on device")

        def close(self) -> None:
            self.handle.close()
            raise OSError(errno.ENOSPC, "No space left on device")

        def fileno(self) -> int:
            return self.handle.fileno()

    root = tmp_path / "ds"
    rng = np.random.default_rng(0)
    writer = DatasetWriter(root, image_size=32, resolution=0.05, num_waypoints=16, expected_instances=1000)
    with pytest.raises(DiskFullError) as info:
        with writer:
            writer._files = {k: FullDisk(h, 200) for k, h in writer._files.items()}
            for _ in range(100):
                writer.add(**synthetic_instance(rng), shape="L", map_id="m", scenario_id="m/0")
    message = str(info.value)
    assert str(root) in message and "MiB" in message and "1000 instances" in message
    assert isinstance(info.value, DatasetError)  # a user error: one line, exit 2, at the entry points
    assert sorted(p.name for p in tmp_path.iterdir()) == []  # no .partial folder, no dataset

    # full already at the end: the flush / fsync fails
    writer = DatasetWriter(root, image_size=32, resolution=0.05, num_waypoints=16)
    with pytest.raises(DiskFullError, match=str(root)):
        with writer:
            writer.add(**synthetic_instance(rng), shape="L", map_id="m", scenario_id="m/0")
            writer._files = {k: FullDisk(h, 10**9) for k, h in writer._files.items()}
    assert sorted(p.name for p in tmp_path.iterdir()) == []


# -- 8. a run that trains and tests nothing ends FINISHED --------------------------------------------------------------
def test_a_run_that_trains_and_tests_nothing_ends_finished(spade_home: Path, tmp_path: Path) -> None:
    """Case 8: ``train=false test=false`` exited 0 and left its MLflow run RUNNING (later marked KILLED)."""
    from mlflow import MlflowClient

    from spade.experiments.run import train

    cfg = compose_row(ROW, spade_home, "train=false", "test=false", f"paths.output_dir={tmp_path / 'out'}",
                      "tags.table=nothing", FID)
    uri = f"sqlite:///{tmp_path}/mlflow.db"
    with open_dict(cfg):
        cfg.paths.mlflow_tracking_uri = uri
        cfg.logger.mlflow.tracking_uri = uri
    train(cfg)
    client = MlflowClient(tracking_uri=uri)
    (run,) = client.search_runs([client.get_experiment_by_name("nothing").experiment_id])
    assert run.info.status == "FINISHED"


# -- 9. report refuses a store that does not exist ---------------------------------------------------------------------
def test_report_refuses_a_store_that_does_not_exist(tmp_path: Path, run_main) -> None:
    """Case 9: ``tracking_uri=sqlite:///<missing dir>/mlflow.db`` created an empty store and reported all missing."""
    from spade.utils.config import compose_config
    from spade.experiments.reporting import report

    store = tmp_path / "missing" / "mlflow.db"
    code, err = run_main("spade.report", [f"tracking_uri=sqlite:///{store}", f"output_dir={tmp_path / 'rep'}"])
    assert code == 2, err
    assert "no MLflow store" in one_error_line(err)
    cfg = compose_config("report", [f"tracking_uri=sqlite:///{store}", f"output_dir={tmp_path / 'rep'}",
                                    "paths.output_dir=."])
    with pytest.raises(ConfigError, match="no MLflow store"):
        report(cfg)
    assert not store.parent.exists() and not (tmp_path / "rep").exists()


@pytest.mark.parametrize("kind", ["foreign_sqlite", "garbage"])
def test_report_reads_without_writing_into_a_file_that_is_not_an_mlflow_store(tmp_path: Path, run_main,
                                                                              kind: str) -> None:
    """With SPADE_HOME holding someone else's SQLite file named ``mlflow.db``, ``spade.report`` created
    about 40 MLflow tables in it. A reader refuses it in one line, the file byte for byte unchanged."""
    import sqlite3

    store = tmp_path / "mlflow.db"
    if kind == "foreign_sqlite":
        db = sqlite3.connect(store)
        db.execute("CREATE TABLE notes (id INTEGER PRIMARY KEY, text TEXT)")
        db.execute("INSERT INTO notes (text) VALUES ('mine')")
        db.commit()
        db.close()
        expected = "is an SQLite database but not an MLflow store"
    else:
        store.write_bytes(b"not a database at all\n" * 100)
        expected = "is not an SQLite database"
    before = store.read_bytes()
    code, err = run_main("spade.report", [f"tracking_uri=sqlite:///{store}", f"output_dir={tmp_path / 'rep'}"])
    assert code == 2, err
    assert expected in one_error_line(err)
    assert store.read_bytes() == before and not (tmp_path / "rep").exists()
    # a run logging there is refused the same way, before any work
    with pytest.raises(ConfigError, match=expected):
        validate_train_config(compose_row("t1_small_bc_L", tmp_path, f"logger.mlflow.tracking_uri=sqlite:///{store}"))
    assert store.read_bytes() == before


# -- 10. every key that shapes the data is checked before any data or prerequisite -------------------------------------
def test_image_size_window_and_unet_downsampling_must_agree(spade_home: Path, tmp_path: Path) -> None:
    """Case 10: ``scale.image_size=62`` alone was ignored (data stayed 64 px); with the window at 62 px too the run
    generated data and trained and registered an expert before failing on "not divisible by 4". The window now
    follows ``scale.image_size`` (one stored size); a window set apart from it is still refused."""
    with pytest.raises(ConfigError, match=r"scale.image_size=64 differs from scale.annotate.window.size_px=60"):
        validate_train_config(compose_row(ROW, spade_home, "scale.annotate.window.size_px=60"))
    with pytest.raises(ConfigError, match=r"window.size_px=62 is not a multiple of 4.*model.size=small"):
        validate_train_config(compose_row(ROW, spade_home, "scale.image_size=62"))
    with pytest.raises(ConfigError, match=r"window.size_px=62 is not a multiple of 4.*model.size=small"):
        validate_train_config(compose_row(ROW, spade_home, "scale.image_size=62", "scale.annotate.window.size_px=62"))
    with pytest.raises(ConfigError, match="not a multiple of 4"):  # the row that trains an expert first, too
        validate_train_config(compose_row("t1_small_conddbc_L", spade_home, "scale.image_size=62",
                                          "scale.annotate.window.size_px=62"))
    # agreeing sizes pass (in a data folder of their own: the shared 64 px tiny datasets would be refused as other
    # settings, which is right)
    validate_train_config(compose_row(ROW, spade_home, "scale.image_size=72", "scale.annotate.window.size_px=72",
                                      f"paths.data_dir={tmp_path}"))


# -- 11. renames by prefix only ----------------------------------------------------------------------------------------
def test_untrained_metrics_are_renamed_by_prefix_only(monkeypatch) -> None:
    """Case 11: ``str.replace("test/", "untrained/")`` also rewrote ``shortest/``: 16 metrics of every run with
    ``test_untrained=true`` were named ``untrained/baseline/shoruntrained/...``."""
    import hydra

    from spade.experiments import run as run_module
    from spade.utils.config import compose_config

    class Tester:
        def test(self, **kwargs):
            return [{"test/ape_cm": 50.0, "test/baseline/shortest/ape_cm": 19.0, "test/baseline/shortest/hd19": 3.0}]

    monkeypatch.setattr(hydra.utils, "instantiate", lambda *a, **k: Tester())
    metrics = run_module.untrained_test_metrics(compose_config("train"), None, None)
    assert metrics == {"untrained/ape_cm": 50.0, "untrained/baseline/shortest/ape_cm": 19.0,
                       "untrained/baseline/shortest/hd19": 3.0}


# -- 12. a fetched prerequisite is checked like an explicit path ------------------------------------------------------
def test_an_expert_fetched_from_the_registry_is_checked_like_an_explicit_path(spade_home: Path, tmp_path: Path,
                                                                             monkeypatch) -> None:
    """Case 12: a prerequisite from the Model Registry skipped the role, kind and geometry checks (they ran before
    the registry filled the path in)."""
    from spade.experiments import prerequisites
    from spade.tracking.registry import RegisteredCheckpoint
    from spade.experiments.run import train

    wrong_role = student_checkpoint(tmp_path / "cache" / "student.ckpt")
    wrong_size = student_checkpoint(tmp_path / "cache" / "expert32.ckpt", role="expert", size=32)
    for fetched, message in ((wrong_role, "is a student checkpoint, this key takes an expert"),
                             (wrong_size, "32 x 32 px")):
        monkeypatch.setattr(prerequisites, "fetch_registered",
                            lambda *a, _p=fetched, **k: RegisteredCheckpoint("expert", 1, "run", _p))
        cfg = compose_row("t1_small_conddbc_L", spade_home, "logger=none", f"paths.output_dir={tmp_path / 'out'}", FID)
        with pytest.raises(ConfigError, match=message) as info:
            train(cfg)
        assert "model.margin.expert_ckpt" in str(info.value)
    assert not (tmp_path / "out" / "checkpoints").exists()  # refused before anything was built


def test_a_registry_expert_of_the_wrong_kind_is_refused_before_training(spade_home: Path, tmp_path: Path,
                                                                       monkeypatch) -> None:
    """An expert fetched from the Model Registry passes the kind check of one given by path. A Cond-DBC
    row whose registry lookup returns an unconditional expert (right role, right window geometry) stops with the
    kind error, naming the key and the fix, before any data module, model or run is built; the same expert by path
    stops the same way."""
    import torch

    from spade.maps.frame import RobotFrame
    from spade.experiments import prerequisites
    from spade.experiments import run as run_module
    from spade.tracking.registry import RegisteredCheckpoint
    from spade.models.builders import build_model

    net = build_model("uncond_expert", "tiny")
    uncond = tmp_path / "cache" / "uncond.ckpt"
    uncond.parent.mkdir(parents=True)
    torch.save({"spade": {"role": "expert", "config": dict(net.config), "data": {
        "image_size": [64, 64], "resolution_m": 0.1, "frame": RobotFrame.for_size(64).to_json()}}}, uncond)
    fetched = []
    monkeypatch.setattr(prerequisites, "fetch_registered",
                        lambda *a, **k: fetched.append(a) or RegisteredCheckpoint("expert", 1, "run", uncond))
    row = ("t1_small_conddbc_L", spade_home, "logger=none", f"paths.output_dir={tmp_path / 'out'}", FID)
    cfg = compose_row(*row)
    built = []
    monkeypatch.setattr(run_module.hydra.utils, "instantiate", lambda *a, **k: built.append(a))
    with pytest.raises(ConfigError, match=r"model.margin.expert_ckpt=.*uncond.ckpt is an unconditional expert, but "
                                          r"Cond-DBC \(margin=cond_dbc\) needs a conditional one; pass a conditional "
                                          r"expert \(a cond_expert_\* experiment\)"):
        run_module.train(cfg)
    assert fetched and not built  # the registry filled the path in; nothing was instantiated after the refusal
    with pytest.raises(ConfigError, match="is an unconditional expert, but Cond-DBC"):
        validate_train_config(compose_row(*row, f"model.margin.expert_ckpt={uncond}"))


# -- part 2: every entry point fails like spade.train -----------------------------------------------------------------
@pytest.fixture
def inputs(tmp_path: Path) -> dict[str, Path]:
    """Files a demanding user points the entry points at: a map, a student, a folder, a plain file, a dataset."""
    from factories import write_synthetic

    out = {"map": site_map(tmp_path / "maps"), "model": student_checkpoint(tmp_path / "student.ckpt"),
           "expert": student_checkpoint(tmp_path / "expert.ckpt", role="expert"), "dir": tmp_path / "a_folder",
           "file": tmp_path / "notes.txt", "dataset": tmp_path / "ds", "missing": tmp_path / "missing.ckpt"}
    out["dir"].mkdir()
    out["file"].write_text("not a model, not a map")
    out["tagged"] = tmp_path / "tagged.yaml"  # a sketch file whose tag would run a command under an unsafe loader
    out["tagged"].write_text("map: warehouse:1\nscenarios: !!python/object/apply:os.system ['echo pwned']\n")
    write_synthetic(out["dataset"], n=3)
    return out


PROBES = [
    # (entry point, arguments with {placeholders}, words the error line must hold)
    ("spade.annotate", ["num_instances=0", "out_dir={dir}/new"], "num_instances=0"),
    ("spade.annotate", ["window.size_px=20", "out_dir={dir}/new"], "too small for a L manoeuvre"),
    ("spade.annotate", ["maps=[{missing}]", "out_dir={dir}/new"], "neither an existing folder"),
    ("spade.annotate", ["sketches={dir}", "out_dir={dir}/new"], "is a directory"),
    ("spade.annotate", ["sketches={missing}", "out_dir={dir}/new"], "does not exist"),
    ("spade.annotate", ["out_dir={file}"], "is an existing file"),
    ("spade.annotate", ["out_dir={dataset}"], "already holds a dataset"),
    ("spade.annotate", ["shape=Z", "out_dir={dir}/new"], "shape='Z'"),
    ("spade.annotate", ["workers=-1", "out_dir={dir}/new"], "workers=-1"),
    ("spade.evaluate", ["ckpt_path={dir}"], "is a directory"),
    ("spade.evaluate", ["ckpt_path={missing}"], "does not exist"),
    ("spade.evaluate", ["ckpt_path={file}"], "not a readable PyTorch checkpoint"),
    ("spade.plan", ["map={map}", "start=[0,1,0]", "goal=[2,1]", "model_path={dir}"], "not a model file"),
    ("spade.plan", ["map={map}", "start=[0,1,0]", "goal=[2,1]", "model_path={dir}/m.ckpt"], "does not exist"),
    ("spade.plan", ["map={map}", "start=[0,1,0]", "goal=[2,1]", "model_path={file}"], "not a model file"),
    ("spade.plan", ["map={map}", "start=[0,1,0]", "goal=[2,1]", "model_path={expert}"], "is an expert checkpoint"),
    ("spade.plan", ["map={map}", "start=[0,1,0]", "goal=[0,1]", "model_path={model}"], "robot's own position"),
    ("spade.plan", ["map={map}", "start=[0,1]", "goal=[2,1]", "model_path={model}"], "is not 3 finite numbers"),
    ("spade.plan", ["map={dir}", "start=[0,1,0]", "goal=[2,1]", "model_path={model}"], "is a directory"),
    ("spade.plan", ["map={missing}", "start=[0,1,0]", "goal=[2,1]", "model_path={model}"], "does not exist"),
    ("spade.plan", ["map={map}", "start=[0,1,0]", "goal=[2,1]", "model_path={model}", "out={dir}"], "is a directory"),
    ("spade.plan", ["map={map}", "start=[0,1,0]", "goal=[2,1]", "model_path={model}", "planner.far_goal=x"],
     "far_goal='x'"),
    ("spade.export", ["ckpt_path={dir}"], "is a directory"),
    ("spade.export", ["ckpt_path={missing}"], "does not exist"),
    ("spade.export", ["ckpt_path={expert}"], "is an expert checkpoint"),
    ("spade.export", ["ckpt_path={model}", "format=tflite"], "format='tflite'"),
    ("spade.export", ["ckpt_path={model}", "out_path={dir}"], "is a directory"),
    ("spade.export", ["ckpt_path={model}", "out_path={dir}/m.pt"], "must end with .onnx"),
    ("spade.report", ["table=table9", "tracking_uri=sqlite:///{dir}/mlflow.db"], "unknown table"),
    ("spade.report", ["tracking_uri=sqlite:///{dir}"], "is a directory"),
    ("spade.sketch", ["map={dir}"], "is a directory"),
    ("spade.sketch", ["map={missing}"], "does not exist"),
    ("spade.sketch", ["map={map}", "port=0"], "port=0"),
    ("spade.sketch", ["map={map}", "model_path={dir}"], "not a model file"),
    ("spade.sketch", ["map={map}", "model_path={expert}"], "is an expert checkpoint"),
    ("spade.sketch", ["map={map}", "out_dir={file}"], "is a file"),
    ("spade.sketch", ["map={map}", "++annotate.window.size_px=20"], "too small"),
    ("spade.annotate", ["sketches={tagged}", "out_dir={dir}/new"], "not a plain YAML sketch file (line 2)"),
    ("spade.bench", ["quick=maybe"], "quick='maybe' is not a boolean"),
    ("spade.bench", ["quick=true", "sections=[nosuch]"], "sections: unknown nosuch"),
    ("spade.annotate", ["overwrite=maybe", "out_dir={dir}/new"], "overwrite='maybe' is not a boolean"),
]


@pytest.mark.parametrize("module, args, words", PROBES, ids=[f"{p[0][6:]}:{p[2][:30]}" for p in PROBES])
def test_every_entry_point_fails_in_one_line_with_exit_2(inputs, run_main, module: str, args: list[str],
                                                         words: str) -> None:
    before = {k: tree(v) if v.is_dir() else digest(v) for k, v in inputs.items() if v.exists()}
    code, err = run_main(module, [a.format(**inputs) for a in args])
    assert code == 2, err
    assert words in one_error_line(err)
    assert {k: tree(v) if v.is_dir() else digest(v) for k, v in inputs.items() if v.exists()} == before
    assert not inputs["missing"].exists()
    hydra_dir = inputs["dir"].parent / "hydra"  # run_main's hydra.run.dir: a refusal leaves no run folder
    assert not hydra_dir.exists(), sorted(p.name for p in hydra_dir.iterdir())


@pytest.mark.parametrize("args, words", [
    (["{missing}"], "does not exist"), (["{file}"], "is a file, not a dataset folder"),
    (["{dir}"], "holds no manifest.json"),
])
def test_data_verify_fails_in_one_line_with_exit_2(inputs, run_main, args: list[str], words: str) -> None:
    code, err = run_main("spade.data.verify", [a.format(**inputs) for a in args], hydra=False)
    assert code == 2, err
    assert words in one_error_line(err)
    assert run_main("spade.data.verify", [str(inputs["dataset"])], hydra=False)[0] == 0


def test_hydra_full_error_shows_the_traceback(inputs, run_main, monkeypatch) -> None:
    monkeypatch.setenv("HYDRA_FULL_ERROR", "1")
    GlobalHydra.instance().clear()
    monkeypatch.setattr(sys, "argv", ["spade.plan", f"map={inputs['map']}", "start=[0,1,0]", "goal=[0,1]",
                                      f"model_path={inputs['model']}", f"hydra.run.dir={inputs['dir']}/h"])
    try:
        with pytest.raises(ConfigError, match="robot's own position"):
            runpy.run_module("spade.plan", run_name="__main__", alter_sys=True)
    finally:
        GlobalHydra.instance().clear()


@pytest.mark.parametrize("module, args", [("spade.train", ["+experiment=nosuch"]),
                                          ("spade.report", ["nosuch_key=1"]),
                                          ("spade.plan", ["planner=[unbalanced"])])
def test_hydras_own_composition_errors_exit_2_like_every_user_error(run_main, module: str, args: list[str]) -> None:
    """Hydra's own errors (an unknown experiment, a key without its +, a malformed override) exited 1,
    where every other user error exits 2. Hydra's message is kept; the status is SPADE's."""
    code, err = run_main(module, args)
    assert code == 2, err
    assert "Traceback" not in err and err.strip(), err
