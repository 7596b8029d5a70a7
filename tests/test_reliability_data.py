"""Reliability of dataset writing: forced races between writers, a writer killed by SIGKILL, stale leftovers."""

from __future__ import annotations

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

from factories import synthetic_instance

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
