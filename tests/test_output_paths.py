"""Outputs: nothing of the user's is ever overwritten (``spade.annotate overwrite=true``, ``spade.export``,
``spade.plan``, ``spade.report``'s pages, ``spade.bench``'s JSON), default outputs are checked like explicit ones,
and an empty, root, read-only or unwritable output or log folder is refused in one line before any work."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from spade.data import DatasetWriter
from spade.data.path_dataset import PathDataset

from factories import site_map, spade_onnx, student_checkpoint, synthetic_instance
from refusal_support import digest, one_error_line, tree


def map_image(yaml_path: Path) -> Path:
    from spade.maps.ros_io import read_map_yaml

    return Path(read_map_yaml(yaml_path).image_path)


def test_annotate_overwrite_refuses_a_folder_or_file_that_is_not_a_dataset(tmp_path: Path, run_main) -> None:
    """``overwrite=true out_dir=X`` deleted whatever X held (datasets, notes, a plain file), exit 0."""
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


def test_export_never_writes_onto_its_checkpoint(tmp_path: Path, run_main) -> None:
    """``ckpt_path=s.pt format=torchscript`` (or ``out_path`` = ``ckpt_path``) overwrote the checkpoint."""
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


def test_plan_never_writes_onto_its_map_or_model(tmp_path: Path, run_main) -> None:
    """``out=<the map's own image>`` overwrote the map; the next plan on it failed."""
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


def test_an_output_that_cannot_be_written_is_refused_in_one_line(tmp_path: Path, run_main) -> None:
    """Read-only outputs ended in a ``PermissionError`` traceback after the work. /proc takes no files,
    whoever runs the test (root included)."""
    code, err = run_main("spade.bench", ["quick=true", "out_json=/proc/spade_bench.json", "sections=[decoder]"])
    assert code == 2, err
    assert "out_json=/proc/spade_bench.json: the folder /proc cannot be written" in one_error_line(err)
    code, err = run_main("spade.annotate", ["out_dir=/proc/spade_ds", "num_instances=2", "maps=[warehouse:1]"])
    assert code == 2 and "out_dir=/proc/spade_ds: the folder /proc" in one_error_line(err), err


def test_a_log_folder_that_cannot_be_written_is_one_line(tmp_path: Path, run_main) -> None:
    """A run folder Hydra cannot make (a read-only ``hydra.run.dir``, ``SPADE_HOME`` or ``paths.log_dir``) was
    Hydra's ``PermissionError`` traceback; ``paths.output_dir`` given a folder of its own likewise. Each is now one
    line naming the folder and the fix, before the command's work. /proc takes no files, whoever runs the test."""
    query = ["map=warehouse:1", "start=[1.0,1.0,0.0]", "goal=[2.0,1.0]", f"out={tmp_path / 'plan.png'}"]
    cases = [
        ("spade.plan", [*query, "hydra.run.dir=/proc/spade_run"], "hydra.run.dir=/proc/spade_run: the folder /proc"),
        ("spade.plan", [*query, "paths.log_dir=/proc/spade_logs"], "hydra.run.dir=/proc/spade_logs/runs/plan/"),
        ("spade.plan", [*query, "paths.output_dir=/proc/spade_out", f"hydra.run.dir={tmp_path / 'run'}"],
         "paths.output_dir=/proc/spade_out: the folder /proc"),
        ("spade.annotate", ["maps=[warehouse:1]", "num_instances=2", f"out_dir={tmp_path / 'ds'}",
                            "hydra.run.dir=/proc/spade_run"], "hydra.run.dir=/proc/spade_run: the folder /proc"),
    ]
    for module, args, expected in cases:
        code, err = run_main(module, args, hydra=False)
        assert code == 2, (args, err)
        line = one_error_line(err)
        assert expected in line and "paths.log_dir=DIR" in line, (args, line)
    assert not (tmp_path / "plan.png").exists() and not (tmp_path / "ds").exists()
    assert not (tmp_path / "run").exists()
