"""Reliability, fourth round: the wrong and unclear cases of the probe, reproduced, and the new
behaviour.

- every option typed and ranged before any work (strict booleans, positive sizes, known metrics), ``spade.critic``
  with a config check of its own, annotation settings ranged wherever a dataset is made;
- late failures moved to the start, and no refused command leaves an MLflow run or a folder behind (a truncated
  dataset is refused before the run is created);
- state: a fresh SQLite store opened by two processes at once, an unreachable tracking server in one line, the
  sketch server's one file for one map;
- docs that match: ``spade.report`` reads unless ``log_to_runs=true``, a dataset of one's own is pointed at
  ``data=own``, ``spade.evaluate`` reads its test set alone;
- read-only outputs, huge map images and maps that would resample to tens of GiB: one line each.
"""

from __future__ import annotations

import json
import struct
import subprocess
import sys
import time
import zlib
from pathlib import Path

import pytest

from factories import site_map, write_synthetic
from test_reliability_outputs import digest, one_error_line, run_main, student_checkpoint  # noqa: F401 - a fixture

REPO = Path(__file__).resolve().parents[1]
UNREACHABLE = "http://127.0.0.1:9/"  # the discard port: nothing answers


def checkpoint(path: Path, role: str = "student", size: int = 32, resolution: float = 0.05) -> Path:
    """A SPADE checkpoint of ``role`` whose window geometry is ``write_synthetic``'s (32 px at 0.05 m/px)."""
    import torch

    from spade.maps.frame import RobotFrame

    student_checkpoint(path, role, size)
    data = torch.load(path, weights_only=False)
    data["spade"]["data"] = {"image_size": [size, size], "resolution_m": resolution,
                             "frame": RobotFrame.for_size(size).to_json()}
    if role == "expert":
        data["spade"]["config"] = {**data["spade"]["config"], "role": "cond_expert"}
    else:  # loadable by Lightning as well (spade.evaluate)
        import lightning

        data.update({"pytorch-lightning_version": lightning.__version__, "hyper_parameters": {"size": "small"}})
    torch.save(data, path)
    return path


def store_runs(uri_path: Path) -> int:
    """The number of runs an SQLite MLflow store holds (0 when there is no store)."""
    import sqlite3

    if not uri_path.exists():
        return 0
    db = sqlite3.connect(uri_path)
    try:
        return int(db.execute("SELECT COUNT(*) FROM runs").fetchone()[0])
    except sqlite3.OperationalError:
        return 0
    finally:
        db.close()


# -- 4. every option typed and ranged before any work --------------------------------------------------------------
@pytest.mark.parametrize("override, key", [("registry.promote=maybe", "registry.promote='maybe' is not a boolean"),
                                           ("registry.promote=1", "registry.promote=1 is not a boolean"),
                                           ("optimized_metric=val/nonexistent",
                                            "optimized_metric=val/nonexistent is not a metric the student logs")])
def test_train_refuses_untyped_values_before_any_work(tmp_path: Path, run_main, override: str, key: str) -> None:
    """``registry.promote=maybe`` was accepted and registered a champion; ``optimized_metric=val/...``
    misspelt failed after the first epoch. Both are one line before any data is made or any run opened."""
    code, err = run_main("spade.train", ["+experiment=t1_small_bc_L", override])
    assert code == 2, err
    line = one_error_line(err)
    assert key in line
    home = tmp_path / "home"
    assert not (home / "data").exists() and store_runs(home / "logs" / "mlflow.db") == 0


def test_the_optimized_metric_is_one_the_role_logs() -> None:
    from spade.config.preflight import fit_metrics, train_options
    from spade.utils.config import compose_config

    student = fit_metrics(train_options(compose_config("train", ["+experiment=t1_small_conddbc_L"])))
    expert = fit_metrics(train_options(compose_config("train", ["+experiment=cond_expert_L"])))
    assert {"val/score_cm", "val/ape_cm", "val/loss_bc", "train/loss_dm", "margin/active"} <= student
    assert "val/loss" in expert and "val/loss_bc" not in expert and "test/ape_cm" not in student


def test_report_booleans_are_strict_and_it_reads_by_default(run_main, tmp_path: Path) -> None:
    """``log_to_runs=maybe`` was accepted (and wrote into every row's run); by default a report wrote its
    chart into the training runs although the guarantees page says readers only read. Now a report writes only
    into ``output_dir`` unless ``log_to_runs=true``."""
    from spade.utils.config import compose_config

    assert compose_config("report", []).log_to_runs is False
    for override in ("log_to_runs=maybe", "chart=1", "paper=yes"):
        code, err = run_main("spade.report", ["table=table1", override])
        assert code == 2, err
        key = override.split("=")[0]
        assert f"{key}=" in one_error_line(err) and "is not a boolean" in err
    assert "log_to_runs=true" in (REPO / "docs" / "reference" / "reliability.md").read_text()


def test_export_checks_latency_batches_and_register_before_writing(tmp_path: Path, run_main) -> None:
    """``latency_batches=[0]`` printed latencies for a batch of 0; bad ``register=`` values failed after
    the export was written (one leaving a registered version without its alias). Each is refused first."""
    ckpt = student_checkpoint(tmp_path / "student.ckpt")
    cases = {"latency_batches=[0]": "latency_batches=[0] holds 0",
             "register=a/b": "register='a/b' is not a registered model name",
             "alias=latest": "alias='latest' is not a model alias",
             "format=torchscript": "only ONNX exports are registered",
             "paths.mlflow_tracking_uri=" + UNREACHABLE: "no tracking server answers there"}
    for override, expected in cases.items():
        extra = [] if override.startswith("latency") else ["register=spade-student"]
        code, err = run_main("spade.export", [f"ckpt_path={ckpt}", "latency_runs=0", *extra, override])
        assert code == 2, err
        assert expected in one_error_line(err), err
        assert not (tmp_path / "student.onnx").exists() and not (tmp_path / "student.pt").exists()


def test_bench_sizes_are_positive(run_main, tmp_path: Path) -> None:
    out = tmp_path / "b.json"
    for override in ("student.batches=[0]", "student.batches=3", "metrics.instances=0"):
        code, err = run_main("spade.bench", ["quick=true", f"out_json={out}", override])
        assert code == 2 and override.split("=")[0] in one_error_line(err), err
    assert not out.exists()


def test_annotation_settings_are_ranged_wherever_a_dataset_is_made(tmp_path: Path, run_main) -> None:
    """``robot.radius_m=-1`` and ``robot.inflation_radius_m=-3`` were written into datasets. Refused by
    spade.annotate, by a run that generates its data and by the sketch server, before any map is loaded."""
    from spade.config.sketch_checks import validate_sketch_config
    from spade.config.annotate_checks import check_annotation_settings
    from spade.utils.config import compose_config
    from spade.utils.errors import ConfigError

    out = tmp_path / "ds"
    for override, expected in (("robot.radius_m=-1", "robot.radius_m=-1 is out of range"),
                               ("robot.inflation_radius_m=-3", "robot.inflation_radius_m=-3 is out of range"),
                               ("instances.spacing_m=0", "instances.spacing_m=0 is out of range"),
                               ("template.p_mirror=2", "template.p_mirror=2 is out of range")):
        code, err = run_main("spade.annotate", [f"out_dir={out}", "num_instances=2", "maps=[warehouse:1]",
                                                "progress=false", override])
        assert code == 2, err
        assert expected in one_error_line(err)
        assert not out.exists()
    with pytest.raises(ConfigError, match=r"data\.train_generate: robot\.radius_m=-1 is out of range"):
        check_annotation_settings({"robot": {"radius_m": -1}}, "data.train_generate: ")
    yaml_path = site_map(tmp_path)
    cfg = compose_config("sketch", [f"map={yaml_path}", f"out_dir={tmp_path / 'sk'}", "++annotate.robot.radius_m=-1"])
    with pytest.raises(ConfigError, match=r"annotate\.robot\.radius_m=-1 is out of range"):
        validate_sketch_config(cfg)


def assert_critic_refuses(run_main, tmp_path: Path, base: list[str], cases: dict[tuple[str, ...], str]) -> None:  # noqa: ANN001
    """Each of ``cases`` (overrides -> the text its one ``error:`` line holds) refused by ``spade.critic`` with exit
    status 2 within 30 s, before any output folder or store is made."""
    for overrides, expected in cases.items():
        start = time.monotonic()
        code, err = run_main("spade.critic", [*base, *overrides])
        assert code == 2, (overrides, err)
        assert expected in one_error_line(err), (overrides, err)
        assert time.monotonic() - start < 30
    assert not (tmp_path / "out").exists() and not (tmp_path / "home" / "logs" / "mlflow.db").exists()


def test_critic_checks_every_input_in_one_line(tmp_path: Path, run_main) -> None:
    """``spade.critic`` had no config check: a garbage store failed after a minute of measuring, and
    every bad input was a traceback. Each is now one line, before the expert is loaded."""
    test = tmp_path / "test"
    write_synthetic(test, n=4)
    expert = checkpoint(tmp_path / "expert.ckpt", "expert")
    student = checkpoint(tmp_path / "student.ckpt")
    garbage = tmp_path / "garbage.db"
    garbage.write_bytes(b"not a database at all" * 100)
    base = [f"ckpt_path={expert}", f"data.test_dir={test}", "data.test_shape=null", f"output_dir={tmp_path / 'out'}"]
    cases = {
        (f"ckpt_path={student}",): "is a student checkpoint, this key takes an expert",
        (f"student_ckpt={expert}",): "student_ckpt=",
        ("critic.bands=0",): "critic.bands=0 is out of range",
        ("critic.draws_per_band=two",): "critic.draws_per_band='two' is not an integer",
        (f"data.test_dir={tmp_path / 'none'}",): "holds no dataset",
        ("data.test_shape=Z",): "data.test_shape='Z'",
        (f"logger.mlflow.tracking_uri=sqlite:///{garbage}",): "is not an SQLite database",
        (f"logger.mlflow.tracking_uri={UNREACHABLE}",): "no tracking server answers there",
        ("model.margin.lambda_dm=-1",): "model.margin.lambda_dm",
        (f"output_dir={garbage}",): "is a file",
    }
    assert_critic_refuses(run_main, tmp_path, base, cases)


def test_evaluate_refuses_source_seed_before_the_evaluation(tmp_path: Path, run_main) -> None:
    """``source_seed=abc`` failed after a whole evaluation, leaving a FINISHED run. Refused first, with
    no run in the store."""
    test = tmp_path / "test"
    write_synthetic(test, n=4)
    ckpt = checkpoint(tmp_path / "student.ckpt")
    for override, expected in (("source_seed=abc", "source_seed='abc' is not an integer"),
                               ("source_seed=-3", "source_seed=-3 is out of range"),
                               ("open_loop=maybe", "open_loop='maybe' is not a boolean"),
                               ("mcap_instances=0", "mcap_instances=0 is out of range")):
        code, err = run_main("spade.evaluate", [f"ckpt_path={ckpt}", "data=own", f"data.test_dir={test}", override])
        assert code == 2, err
        assert expected in one_error_line(err)
    assert store_runs(tmp_path / "home" / "logs" / "mlflow.db") == 0


# -- 4. data checked before the run is created ---------------------------------------------------------------------
def test_a_truncated_dataset_is_refused_before_the_mlflow_run(tmp_path: Path, run_main) -> None:
    """Clear one-line refusals of truncated, empty or edited datasets still left a FAILED MLflow run (the
    loaders ran inside the run). The data is now opened by the config check, before any run exists."""
    train, test = tmp_path / "train", tmp_path / "test"
    write_synthetic(train, n=12)
    write_synthetic(test, n=4, seed=1)
    array = max((p for p in train.iterdir() if p.name != "manifest.json" and p.is_file()),
                key=lambda p: p.stat().st_size)
    data = array.read_bytes()
    array.write_bytes(data[: len(data) // 2])  # truncated
    store = tmp_path / "home" / "logs" / "mlflow.db"
    code, err = run_main("spade.train", ["+experiment=t1_small_bc_L", "data=own", f"data.train_dir={train}",
                                         f"data.test_dir={test}", "scale.image_size=32", "scale.resolution_m=0.05"])
    assert code == 2, err
    line = one_error_line(err)
    assert "data.train_dir=" in line and "truncated" in line and str(array) in line
    assert store_runs(store) == 0
    array.write_bytes(data[:-1] + bytes([data[-1] ^ 0xFF]))  # the right size, edited: the checksum says so
    code, err = run_main("spade.train", ["+experiment=t1_small_bc_L", "data=own", f"data.train_dir={train}",
                                         f"data.test_dir={test}", "scale.image_size=32", "scale.resolution_m=0.05"])
    assert code == 2 and "sha256" in one_error_line(err), err
    assert store_runs(store) == 0


def test_a_users_dataset_under_a_generated_data_config_is_pointed_at_data_own(tmp_path: Path) -> None:
    """``spade.evaluate ... data=lshape data.test_dir=<a test set the user annotated>`` was refused as
    "generated with other settings" with fixes that never named ``data=own``."""
    from spade.data.checks import DatasetSettingsError, check_dataset
    from spade.utils.config import compose_config

    mine = tmp_path / "mine"
    write_synthetic(mine, n=3)
    cfg = compose_config("evaluate", ["ckpt_path=x", f"data.test_dir={mine}"])
    from omegaconf import OmegaConf

    with pytest.raises(DatasetSettingsError) as info:
        check_dataset(mine, OmegaConf.to_container(cfg.data.test_generate, resolve=True), "data.test_dir")
    assert "generated with other settings" in str(info.value) and f"pass data=own with data.test_dir={mine}" in str(
        info.value)


def test_testing_reads_the_test_set_alone(tmp_path: Path) -> None:
    """``spade.evaluate data=own data.test_dir=DIR`` on a machine without a training set failed with
    "<home>/data/quickstart/lshape: dataset missing ...". A test with a test set of its own neither builds nor
    reads the training set; a later training still checks the pair."""
    from types import SimpleNamespace

    from lightning.pytorch.trainer.states import TrainerFn

    from spade.data.datamodule import PathDataModule

    test = tmp_path / "test"
    write_synthetic(test, n=6)
    dm = PathDataModule(train_dir=tmp_path / "no_training_set", test_dir=test, test_shape=None, batch_size=2)
    dm.trainer = SimpleNamespace(state=SimpleNamespace(fn=TrainerFn.TESTING))
    dm.prepare_data()
    dm.setup("test")
    assert dm.train_set is None and len(dm.test_set) == 6
    assert dm.image_size == (32, 32) and dm.resolution == pytest.approx(0.05)
    assert not (tmp_path / "no_training_set").exists()
    dm.trainer = SimpleNamespace(state=SimpleNamespace(fn=TrainerFn.FITTING))
    from spade.data import DatasetError

    with pytest.raises(DatasetError, match="dataset missing and no generator config given"):
        dm.prepare_data()  # training does need it: said so, with data=own's fix
    with pytest.raises(DatasetError, match="data.train_dir is not set"):
        PathDataModule(train_dir=None, test_dir=test).setup("fit")


@pytest.mark.slow  # a whole evaluation (an untrained student on a synthetic test set)
def test_evaluate_with_own_test_set_and_no_training_set(tmp_path: Path, run_main) -> None:
    test = tmp_path / "test"
    write_synthetic(test, n=6)
    ckpt = checkpoint(tmp_path / "student.ckpt")
    code, err = run_main("spade.evaluate", [f"ckpt_path={ckpt}", "data=own", f"data.test_dir={test}",
                                            "data.test_shape=null", "logger=none", "+trainer.limit_test_batches=1"])
    assert code == 0, err[-3000:]
    assert not (tmp_path / "home" / "data").exists()


# -- 5. state: the store, the server, the sketch file --------------------------------------------------------------
def test_an_unreachable_tracking_server_fails_fast_in_one_line(run_main) -> None:
    """``spade.report tracking_uri=http://127.0.0.1:9/`` retried silently for 253 s, then a traceback."""
    start = time.monotonic()
    code, err = run_main("spade.report", ["table=table1", f"tracking_uri={UNREACHABLE}"])
    assert code == 2, err
    assert "no tracking server answers there" in one_error_line(err)
    assert time.monotonic() - start < 20


_RACE = """
import sys, time
uri, mode, start = sys.argv[1], sys.argv[2], float(sys.argv[3])
if mode == "spade":
    from spade.tracking.client import ensure_store as open_store
else:
    from mlflow import MlflowClient
    open_store = lambda uri: MlflowClient(tracking_uri=uri).search_experiments()
while time.time() < start:
    time.sleep(0.001)
open_store(uri)
print("ok")
"""


@pytest.mark.slow  # processes racing on a fresh store
def test_two_processes_create_a_fresh_store_safely(tmp_path: Path) -> None:
    """Two ``spade.train`` on a fresh store crashed one of them (``duplicate column name: outputs`` while
    MLflow created its tables). SPADE opens a fresh SQLite store under a file lock: both succeed, every time."""
    for attempt in range(3):
        uri = f"sqlite:///{tmp_path / f'store{attempt}' / 'mlflow.db'}"
        start = time.time() + 15  # both imported and waiting by then
        procs = [subprocess.Popen([sys.executable, "-c", _RACE, uri, "spade", str(start)], cwd=REPO,
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for _ in range(2)]
        outs = [p.communicate(timeout=300) for p in procs]
        assert all(p.returncode == 0 for p in procs), [o[1][-2000:] for o in outs]
        from mlflow import MlflowClient

        assert MlflowClient(tracking_uri=uri).search_experiments()  # the Default experiment: a complete store


def _sketch_client(yaml_path: Path, out: Path):
    pytest.importorskip("fastapi")
    pytest.importorskip("httpx")
    from fastapi.testclient import TestClient

    from spade.sketching import build_app
    from test_sketch_api import LOCAL, TINY

    return TestClient(build_app(str(yaml_path), out, TINY), base_url=LOCAL)


def test_one_sketch_file_one_map(tmp_path: Path) -> None:
    """Two sketch servers on one ``out_dir`` with different maps both saved (``sketches.yaml`` named one
    map and held the other's sketch), and an edit of the file's ``map:`` while a server ran was ignored. The file's
    map is checked on every request: a file of another map is refused (409), never written into."""
    from spade.maps import OccupancyMap, save_ros_map
    from test_sketch_api import L_WAYPOINTS

    first = site_map(tmp_path / "a")
    import numpy as np

    g = np.ones((100, 120), np.uint8)
    g[[0, -1], :] = 2
    g[:, [0, -1]] = 2
    second = save_ros_map(OccupancyMap(g, 0.1, origin=(-2.0, -1.0, 0.0), name="other"), tmp_path / "b" / "other.yaml")
    out = tmp_path / "sketches"
    a, b = _sketch_client(first, out), _sketch_client(second, out)  # neither has saved yet: both start
    r = a.post("/api/sketches", json={"shape": "L", "waypoints": L_WAYPOINTS})
    assert r.status_code == 201, r.text
    before = digest(out / "sketches.yaml")
    r = b.post("/api/sketches", json={"shape": "L", "waypoints": L_WAYPOINTS})
    assert r.status_code == 409 and "holds sketches of map" in r.json()["error"], r.text
    assert b.get("/api/sketches").status_code == 409
    assert digest(out / "sketches.yaml") == before
    with pytest.raises(ValueError, match="holds sketches of map"):
        _sketch_client(second, out)  # a second server of another map, started now: refused
    # the file's map edited while the server runs: refused, not ignored
    text = (out / "sketches.yaml").read_text()
    (out / "sketches.yaml").write_text(text.replace(str(first.resolve()), str(second.resolve())))
    r = a.post("/api/sketches", json={"shape": "L", "waypoints": L_WAYPOINTS})
    assert r.status_code == 409 and "holds sketches of map" in r.json()["error"]


def test_sketch_server_answers_4xx_for_a_nul_byte_and_a_corrupted_file(tmp_path: Path) -> None:
    """A NUL byte in a model path and a corrupted ``sketches.yaml`` answered 500."""
    yaml_path = site_map(tmp_path)
    out = tmp_path / "sk"
    client = _sketch_client(yaml_path, out)
    r = client.post("/api/model", json={"path": "stud\x00ent.onnx"})
    assert r.status_code == 400 and "NUL byte" in r.json()["error"], r.text
    out.mkdir(exist_ok=True)
    (out / "sketches.yaml").write_text("map: [unclosed\n  scenarios: {\n")
    for r in (client.get("/api/sketches"),
              client.post("/api/sketches", json={"shape": "L", "waypoints": [[0.0, 1.0], [1.5, 1.0]]})):
        assert r.status_code in (409, 422) and "error" in r.json(), r.text
    r = client.get("/api/sketches")
    assert r.status_code == 409 and "is not readable YAML" in r.json()["error"]
    (out / "sketches.yaml").write_text("map: x\nscenarios: [1, 2]\n")
    r = client.get("/api/sketches")
    assert r.status_code == 409 and "not a list of sketches" in r.json()["error"]


# -- read-only outputs, huge maps ----------------------------------------------------------------------------------
def test_an_output_that_cannot_be_written_is_refused_in_one_line(tmp_path: Path, run_main) -> None:
    """Read-only outputs ended in a ``PermissionError`` traceback after the work. /proc takes no files,
    whoever runs the test (root included)."""
    code, err = run_main("spade.bench", ["quick=true", "out_json=/proc/spade_bench.json", "sections=[decoder]"])
    assert code == 2, err
    assert "out_json=/proc/spade_bench.json: the folder /proc cannot be written" in one_error_line(err)
    code, err = run_main("spade.annotate", ["out_dir=/proc/spade_ds", "num_instances=2", "maps=[warehouse:1]"])
    assert code == 2 and "out_dir=/proc/spade_ds: the folder /proc" in one_error_line(err), err


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


def test_guarantees_page_says_what_report_writes() -> None:
    text = (REPO / "docs" / "reference" / "reliability.md").read_text()
    assert "log_to_runs=true" in text and "data=own" in text
    assert json.dumps  # the module's imports stay used
