"""Datasets that are what they claim: forced races between writers, a writer killed by SIGKILL, stale leftovers,
a full disk; a manifest without its checksum, a truncated, edited or poisoned (NaN, absurd values) dataset refused by
``verify`` and by every loader alike, before any run is created; a test set read alone."""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from spade.data import DatasetWriter, read_manifest
from spade.data.path_dataset import PathDataset
from spade.data.verify import verify
from spade.data.writer import process_owner as _owner, remove_stale_partials

from factories import checkpoint, synthetic_instance, write_synthetic
from refusal_support import one_error_line, store_runs

REPO = Path(__file__).resolve().parents[1]


def _writer(root: Path, seed: int, overwrite: bool = False) -> DatasetWriter:
    return DatasetWriter(root, image_size=32, resolution=0.05, num_waypoints=16, generator_config={"seed": seed},
                         overwrite=overwrite)


def _fill(writer: DatasetWriter, seed: int, n: int = 3) -> None:
    rng = np.random.default_rng(seed)
    for i in range(n):
        writer.add(**synthetic_instance(rng), shape="L", map_id="m", scenario_id=f"m/{seed}-{i}")


def _leftovers(parent: Path) -> list[str]:
    return sorted(p.name for p in parent.iterdir() if ".partial-" in p.name or ".old-" in p.name)


def test_two_writers_racing_for_one_missing_dataset_the_second_fails_and_the_first_is_kept(tmp_path: Path,
                                                                                            monkeypatch) -> None:
    """Forced race: both writers start while the dataset is missing (two spade.annotate into one out_dir), the
    first finishes, and the second, without overwrite, fails instead of replacing it; then,
    with overwrite, one swaps while the other is mid-swap."""
    from spade.data.writer import DatasetExistsError

    root = tmp_path / "ds"
    a, b = _writer(root, 1), _writer(root, 2)  # both pass the "does it exist" check
    with pytest.raises(DatasetExistsError, match="another writer created a dataset there"):
        with a:
            with b:
                assert len(_leftovers(tmp_path)) == 2
                _fill(a, 1)
                _fill(b, 2)
                # a's cleanup of stale leftovers must not touch b's live partial folder (same host, live pid)
                assert remove_stale_partials(root) == []
            assert read_manifest(root).generator == {"seed": 2} and verify(root) == []
    assert read_manifest(root).generator == {"seed": 2} and verify(root) == []  # the first complete one stays
    assert _leftovers(tmp_path) == []

    # The swap itself raced: a parallel writer's dataset lands at root between our two renames.
    landed = tmp_path / "landing"
    with _writer(landed, 4) as other:
        _fill(other, 4)
    real_replace = os.replace
    calls: list[tuple[str, str]] = []

    def racing_replace(src, dst) -> None:
        calls.append((Path(src).name, Path(dst).name))
        if len(calls) == 2:  # root was moved aside; before ours moves in, the other one arrives
            real_replace(landed, root)
        real_replace(src, dst)

    monkeypatch.setattr(os, "replace", racing_replace)
    with _writer(root, 3, overwrite=True) as c:
        _fill(c, 3)
    monkeypatch.setattr(os, "replace", real_replace)
    assert len(calls) >= 4  # the swap failed once and was done again
    assert read_manifest(root).generator == {"seed": 3} and verify(root) == []
    assert _leftovers(tmp_path) == [] and not landed.exists()


_KILLED_WRITER = """
import sys, time
import numpy as np
sys.path.insert(0, {tests!r})
from factories import synthetic_instance
from spade.data import DatasetWriter
w = DatasetWriter({root!r}, image_size=32, resolution=0.05, num_waypoints=16, overwrite=True)
w.__enter__()
rng = np.random.default_rng(0)
for i in range(5):
    w.add(**synthetic_instance(rng), shape="L", map_id="m", scenario_id=f"m/{{i}}")
print("writing", flush=True)
time.sleep(600)
"""


def test_writer_killed_mid_write_leaves_old_dataset_and_next_write_removes_its_folder(tmp_path: Path) -> None:
    root = tmp_path / "ds"
    with _writer(root, 1) as w:
        _fill(w, 1)
    before = (root / "manifest.json").read_bytes()
    code = _KILLED_WRITER.format(tests=str(REPO / "tests"), root=str(root))
    proc = subprocess.Popen([sys.executable, "-c", code], cwd=REPO, stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "writing"
        assert proc.poll() is None  # alive, mid-write, when killed
        partial = [p for p in tmp_path.iterdir() if ".partial-" in p.name]
        assert len(partial) == 1 and f"-{proc.pid}-" in partial[0].name
        # while it lives, another writer's cleanup leaves its folder alone
        assert remove_stale_partials(root) == [] and partial[0].exists()
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.kill()
        proc.wait()
    assert (root / "manifest.json").read_bytes() == before and verify(root) == []
    assert partial[0].exists()  # what the killed writer left ...
    with _writer(root, 2, overwrite=True) as w:  # ... is removed by the next write to the same place
        _fill(w, 2)
    assert _leftovers(tmp_path) == [] and read_manifest(root).generator == {"seed": 2}


def test_stale_partial_rules(tmp_path: Path) -> None:
    root = tmp_path / "ds"
    host = _owner().rsplit("-", 1)[0]
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        names = {
            "dead": f".ds.partial-{host}-{dead.pid}-00000001",
            "live": f".ds.partial-{host}-{live.pid}-00000002",
            "other_host": f".ds.partial-elsewhere.example-{dead.pid}-00000003",
            "legacy_old": ".ds.partial-0000abcd",
            "legacy_new": ".ds.partial-0000abce",
            "other_dataset": f".dsx.partial-{host}-{dead.pid}-00000004",
        }
        for name in names.values():
            (tmp_path / name).mkdir()
        old = time.time() - 2 * 3600
        os.utime(tmp_path / names["legacy_old"], (old, old))
        removed = {p.name for p in remove_stale_partials(root)}
        assert removed == {names["dead"], names["legacy_old"]}
        assert all((tmp_path / names[k]).exists() for k in ("live", "other_host", "legacy_new", "other_dataset"))
    finally:
        live.kill()
        live.wait()


def test_a_tampered_manifest_is_refused_by_verify_and_by_loading(tmp_path: Path) -> None:
    """``spade.data.verify`` answered "OK ... verified" for a manifest whose ``resolution`` was edited
    (0.05 -> 0.1 m/px rescales every cm metric). The manifest's own checksum refuses the edit; a manifest whose
    checksum was recomputed after the edit is still refused where its geometry disagrees with its own records."""
    import json

    from spade.data import DatasetError
    from spade.data.path_dataset import PathDataset
    from spade.data.format import MANIFEST_CHECKSUM, manifest_checksum
    from spade.data.verify import verify

    from factories import write_synthetic

    root = tmp_path / "ds"
    write_synthetic(root, n=4)
    assert verify(root) == []
    manifest = root / "manifest.json"
    raw = json.loads(manifest.read_text())
    assert raw[MANIFEST_CHECKSUM] == manifest_checksum(raw)
    raw["resolution"] = 0.1
    manifest.write_text(json.dumps(raw))
    (problem,) = verify(root)
    assert "changed after it was written" in problem and str(manifest) in problem
    with pytest.raises(DatasetError, match="changed after it was written"):
        PathDataset(root)
    raw["resolution"], raw["frame"]["size_px"] = 0.05, raw["image_size"][1] * 2  # a consistent checksum, wrong frame
    raw[MANIFEST_CHECKSUM] = manifest_checksum(raw)
    manifest.write_text(json.dumps(raw))
    with pytest.raises(DatasetError, match=r"image_size .* disagrees with frame.size_px"):
        PathDataset(root)


def test_a_leak_is_found_by_content_not_by_scenario_names(tmp_path: Path) -> None:
    """Two datasets made on one map always "shared scenarios" (ids are per-map counters such as
    site/L000), whatever their seeds. Now a test set on the same map with other demonstrations is accepted and a
    test window identical to a training window is refused, naming its scenario."""
    import shutil

    from spade.data import DatasetError
    from spade.data.datamodule import PathDataModule

    from factories import write_synthetic

    write_synthetic(tmp_path / "train", n=9, seed=0)
    write_synthetic(tmp_path / "test", n=6, seed=1)  # the same scenario ids (map0/s0 ...), other demonstrations
    dm = PathDataModule(tmp_path / "train", tmp_path / "test", val_fraction=0.3, batch_size=2)
    dm.setup("test")
    assert len(dm.test_set) == 6
    shutil.copytree(tmp_path / "train", tmp_path / "copy")
    dm = PathDataModule(tmp_path / "train", tmp_path / "copy", val_fraction=0.3, batch_size=2)
    with pytest.raises(DatasetError, match=r"9 test scenarios \(map0/s0, .* and 4 more\) are training scenarios .* a "
                                           r"leak"):
        dm.setup("test")


def test_disk_full_removes_the_partial_folder_and_names_path_and_space(tmp_path: Path) -> None:
    """ENOSPC while writing, then again in ``close()``, left a ``.partial`` folder and an error that named
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


def _strip_checksum(root: Path) -> Path:
    """A hand edit: resolution and the generator record changed, ``manifest_sha256`` deleted."""
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
    ("pose", np.nan, 0, "holds NaN or inf"),  # every pose NaN
    ("pose", np.inf, 2, "holds NaN or inf"),
    ("pose", 1e30, 1, "a pose beyond 1e+06 m"),
    ("pose", 5000.0, 2, "a yaw beyond 1000 rad"),
    ("waypoints", 1e30, 0, "window pixel coordinates beyond 3200"),  # finite absurd data failing late
])
def test_verify_and_the_loaders_refuse_the_same_absurd_values(tmp_path: Path, name: str, value: float, column: int,
                                                               says: str) -> None:
    """``spade.data.verify`` reported OK for a dataset whose every pose is NaN (``spade.evaluate`` refused
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
