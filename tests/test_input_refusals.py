"""Every entry point checks its inputs first: a missing, misplaced or foreign file, a folder for a file, an unsafe
sketch file, a procedural map spec with a bad seed, a registry version that does not exist, a map too large to read.
Each refusal is one ``error: ...; <fix>`` line and exit status 2, every input left as it was; Hydra's own errors exit 2
as well.

The entry points run in this process (their Hydra ``main`` with a patched ``sys.argv``: the ``run_main`` fixture),
which is what ``python -m spade.X`` runs after its argument shorthands; the command lines as processes are in
``test_command_processes.py`` (marked slow).
"""

from __future__ import annotations

import runpy
import struct
import sys
import zlib
from pathlib import Path

import pytest
from hydra.core.global_hydra import GlobalHydra

from spade.utils.errors import ConfigError

from factories import site_map, student_checkpoint
from refusal_support import digest, one_error_line, tree


@pytest.mark.parametrize("module, args", [
    ("spade.plan", ["map=warehouse:abc", "start=[0.0,1.0,0.0]", "goal=[2.0,1.0]"]),
    ("spade.plan", ["warehouse:abc", "start=0,1,0", "goal=2,1"]),  # the map as the leading positional
    ("spade.annotate", ["maps=[warehouse:abc]", "num_instances=5", "out_dir={tmp}/ds"]),
    ("spade.annotate", ["maps=warehouse:abc", "num_instances=5", "out_dir={tmp}/ds"]),
    ("spade.sketch", ["map=warehouse:abc"]),
])
def test_a_procedural_spec_with_a_non_integer_seed_is_one_line(tmp_path: Path, run_main, module: str,
                                                               args: list[str]) -> None:
    """``warehouse:abc`` wherever a map spec is accepted: one line naming the spec and an integer seed."""
    code, err = run_main(module, [a.format(tmp=tmp_path) for a in args])
    assert code == 2, err
    line = one_error_line(err)
    assert "warehouse:abc" in line and "is not an integer" in line and "warehouse:3" in line, line
    assert not (tmp_path / "ds").exists()


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


def _png_header(path: Path, width: int, height: int) -> Path:
    """A PNG whose header claims ``width`` x ``height`` grey pixels (its data is not needed to read the size)."""
    path.parent.mkdir(parents=True, exist_ok=True)

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\x00" * 64))
                     + chunk(b"IEND", b""))
    return path


def _map_yaml(folder: Path, image: Path, resolution: float) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    yaml_path = folder / "big.yaml"
    yaml_path.write_text(f"image: {image.name}\nresolution: {resolution}\norigin: [0.0, 0.0, 0.0]\nnegate: 0\n"
                         "occupied_thresh: 0.65\nfree_thresh: 0.196\n")
    return yaml_path


def test_huge_maps_are_refused_before_they_are_read(tmp_path: Path, run_main) -> None:
    """A huge map image raised PIL's DecompressionBombError; a map at 5 m/cell asked for 37 GiB once
    resampled to the window's 0.05 m/px. Both are one line, from the image's header, before any work."""
    big = _map_yaml(tmp_path / "big", _png_header(tmp_path / "big" / "big.png", 20000, 20000), 0.05)
    coarse = _map_yaml(tmp_path / "coarse", _png_header(tmp_path / "coarse" / "big.png", 1000, 1000), 5.0)
    code, err = run_main("spade.annotate", [f"out_dir={tmp_path / 'ds'}", f"maps=[{big}]", "num_instances=2"])
    assert code == 2 and "20000 x 20000 px" in one_error_line(err) and "at most 100 M cells" in err, err
    code, err = run_main("spade.annotate", [f"out_dir={tmp_path / 'ds'}", f"maps=[{coarse}]", "num_instances=2"])
    line = one_error_line(err)
    assert code == 2 and "resampled to 0.05 m/px is 100000 x 100000 cells" in line and "GiB" in line, err
    code, err = run_main("spade.plan", [f"map={big}", "start=[1.0,1.0,0.0]", "goal=[3.0,1.0]",
                                        f"model_path={student_checkpoint(tmp_path / 's.ckpt')}",
                                        f"out={tmp_path / 'plan.png'}"])
    assert code == 2 and "20000 x 20000 px" in one_error_line(err), err
    assert not (tmp_path / "ds").exists() and not (tmp_path / "plan.png").exists()


def test_a_missing_registry_version_names_the_versions_that_exist(tmp_path: Path, run_main) -> None:
    """``model=models:/NAME/99`` answered MLflow's error for an unknown version; now one line naming the versions
    (and aliases) NAME has, and an unknown name is answered with the names that are registered."""
    from factories import site_map
    from spade.deploy.mlflow_models import mlflow_client
    from spade.deploy.mlflow_store import ensure_store

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    ensure_store(uri)
    client = mlflow_client(uri)
    client.create_registered_model("stu")
    for _ in range(2):
        client.create_model_version("stu", source=str(tmp_path / "nowhere"))
    client.set_registered_model_alias("stu", "champion", "2")
    yaml_path = site_map(tmp_path)
    query = [f"map={yaml_path}", "start=[0.0,1.0,0.0]", "goal=[2.0,1.0]", f"paths.mlflow_tracking_uri={uri}",
             f"out={tmp_path / 'plan.png'}"]
    code, err = run_main("spade.plan", [*query, "model_path=models:/stu/99"])
    assert code == 2, err
    line = one_error_line(err)
    assert "models:/stu/99" in line and "stu has versions [1, 2]" in line and "champion" in line, line
    code, err = run_main("spade.plan", [*query, "model_path=models:/stu@best"])
    assert code == 2 and "stu has versions [1, 2]" in one_error_line(err), err
    code, err = run_main("spade.plan", [*query, "model_path=models:/other/1"])
    assert code == 2, err
    line = one_error_line(err)
    assert "no model is registered as 'other'" in line and "['stu']" in line, line
    assert not (tmp_path / "plan.png").exists()
