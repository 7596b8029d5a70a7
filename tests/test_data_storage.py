"""Dataset storage: round trip, atomicity and detection of damaged files."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
import torch

from spade.data import DatasetError, DatasetWriter, read_manifest
from spade.data.path_dataset import PathDataset
from spade.data.packing import pack_bits, pack_two_bit, unpack_bits, unpack_two_bit
from spade.data.verify import main as verify_main

from factories import synthetic_instance, write_synthetic


def test_packing_round_trip_odd_sizes() -> None:
    rng = np.random.default_rng(1)
    for n in (1, 5, 64, 1023):
        codes = rng.integers(0, 3, n).astype(np.uint8)
        assert np.array_equal(unpack_two_bit(pack_two_bit(codes), n), codes)
        bits = rng.integers(0, 2, n).astype(bool)
        assert np.array_equal(unpack_bits(pack_bits(bits), n).astype(bool), bits)


def test_round_trip(tmp_path: Path) -> None:
    items = write_synthetic(tmp_path / "ds", n=12)
    ds = PathDataset(tmp_path / "ds")
    assert len(ds) == 12 and ds.image_size == (32, 32)
    for i, ref in enumerate(items):
        item = ds[i]
        assert item["state"].dtype == torch.float32 and item["state"].shape == (3, 32, 32)
        assert np.array_equal(item["state"][0].numpy(), ref["occupancy"] * 0.5)
        assert np.array_equal(item["state"][1].numpy(), ref["start"].astype(np.float32))
        assert np.array_equal(item["state"][2].numpy(), ref["goal"].astype(np.float32))
        assert np.array_equal(item["path"][0].numpy(), ref["path"].astype(np.float32))
        assert np.array_equal(item["waypoints"].numpy(), ref["waypoints"])
        assert (item["shape"], item["map_id"], item["scenario_id"]) == (ref["shape"], ref["map_id"], ref["scenario_id"])
        assert item["resolution"] == 0.05
    assert set(np.unique(ds[0]["state"][0].numpy())) <= {0.0, 0.5, 1.0}
    manifest = read_manifest(tmp_path / "ds")
    assert manifest.extra == {"rejections": {"collision": 1}}
    assert manifest.generator == {"seed": 0}
    batch = next(iter(torch.utils.data.DataLoader(ds, batch_size=4)))
    assert batch["state"].shape == (4, 3, 32, 32) and batch["waypoints"].shape == (4, 16, 2)
    assert ds[-1]["index"] == 11
    with pytest.raises(IndexError):
        ds[12]


def test_dataloader_workers_reopen_maps(tmp_path: Path) -> None:
    write_synthetic(tmp_path / "ds", n=8)
    ds = PathDataset(tmp_path / "ds")
    loader = torch.utils.data.DataLoader(ds, batch_size=4, num_workers=2, multiprocessing_context="spawn")
    paths = torch.cat([b["path"] for b in loader])
    assert torch.equal(paths, torch.stack([ds[i]["path"] for i in range(8)]))


def test_same_input_gives_identical_bytes(tmp_path: Path) -> None:
    write_synthetic(tmp_path / "a", n=6, seed=3)
    write_synthetic(tmp_path / "b", n=6, seed=3)
    for name in ("manifest.json", "occupancy.bin", "path.bin", "waypoints.bin"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()


@pytest.mark.parametrize("damage", ["flip", "truncate", "missing", "manifest"])
def test_damage_is_detected_and_named(tmp_path: Path, damage: str) -> None:
    root = tmp_path / "ds"
    write_synthetic(root, n=6)
    target = root / "path.bin"
    if damage == "flip":
        data = bytearray(target.read_bytes())
        data[len(data) // 2] ^= 0x01
        target.write_bytes(bytes(data))
        expected = "altered"
    elif damage == "truncate":
        target.write_bytes(target.read_bytes()[:-3])
        expected = "truncated"
    elif damage == "missing":
        target.unlink()
        expected = "missing"
    else:
        target = root / "manifest.json"
        target.write_text(target.read_text()[:-20])
        expected = "JSON"
    with pytest.raises(DatasetError, match=expected) as info:
        PathDataset(root)
    assert str(target) in str(info.value)
    assert verify_main([str(root)]) == 1


def test_verify_cli_accepts_sound_dataset(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    write_synthetic(tmp_path / "ds", n=5)
    assert verify_main([str(tmp_path / "ds")]) == 0
    assert "OK - 5 instances" in capsys.readouterr().out


def test_verify_finds_domain_errors(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    inst = synthetic_instance(rng)
    inst["waypoints"] = inst["waypoints"][::-1].copy()  # the first point now sits in the goal disc
    with DatasetWriter(tmp_path / "ds", image_size=32, resolution=0.05, num_waypoints=16) as w:
        w.add(**inst, shape="L", map_id="m", scenario_id="m/0")
    from spade.data.verify import verify

    problems = verify(tmp_path / "ds")
    assert any("start disc" in p for p in problems)


def test_interrupted_write_leaves_nothing(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    with pytest.raises(KeyboardInterrupt):
        with DatasetWriter(tmp_path / "ds", image_size=32, resolution=0.05, num_waypoints=16) as w:
            w.add(**synthetic_instance(rng), shape="L", map_id="m", scenario_id="m/0")
            raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []


def test_existing_dataset_is_never_lost(tmp_path: Path) -> None:
    root = tmp_path / "ds"
    write_synthetic(root, n=4)
    before = (root / "manifest.json").read_bytes()
    with pytest.raises(FileExistsError, match="overwrite"):
        DatasetWriter(root, image_size=32, resolution=0.05, num_waypoints=16)
    rng = np.random.default_rng(0)
    with pytest.raises(ValueError, match="shape"):
        with DatasetWriter(root, image_size=32, resolution=0.05, num_waypoints=16, overwrite=True) as w:
            w.add(**synthetic_instance(rng, size=16), shape="L", map_id="m", scenario_id="m/0")
    assert (root / "manifest.json").read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"]
    with DatasetWriter(root, image_size=32, resolution=0.05, num_waypoints=16, overwrite=True) as w:
        w.add(**synthetic_instance(rng), shape="U", map_id="m", scenario_id="m/0")
    assert len(PathDataset(root)) == 1


def test_bad_instances_are_refused(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    inst = synthetic_instance(rng)
    with DatasetWriter(tmp_path / "ds", image_size=32, resolution=0.05, num_waypoints=16) as w:
        with pytest.raises(ValueError, match="UNKNOWN=0"):
            w.add(**{**inst, "occupancy": inst["occupancy"] * 3}, shape="L", map_id="m", scenario_id="s")
        with pytest.raises(ValueError, match=r"\(16, 2\)"):
            w.add(**{**inst, "waypoints": inst["waypoints"][:5]}, shape="L", map_id="m", scenario_id="s")
        w.add(**inst, shape="L", map_id="m", scenario_id="s")
    assert len(PathDataset(tmp_path / "ds")) == 1


def test_missing_directory_message_names_fix(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="spade.annotate"):
        PathDataset(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DatasetError, match="manifest.json is missing"):
        PathDataset(tmp_path / "empty")


def test_release_pages_keeps_reading_correct(tmp_path: Path) -> None:
    write_synthetic(tmp_path / "ds", n=9)
    a = PathDataset(tmp_path / "ds", release_every=2)
    b = PathDataset(tmp_path / "ds", release_every=0)
    for i in range(9):
        assert torch.equal(a[i]["state"], b[i]["state"])
    assert os.path.exists(tmp_path / "ds" / "manifest.json")
    json.loads((tmp_path / "ds" / "manifest.json").read_text())


def test_settings_that_never_change_the_bytes_do_not_make_a_dataset_stale() -> None:
    """How a dataset is made (workers, the states per worker task, progress bars) is not what it is: a dataset
    generated before ``states_per_task`` existed is still the dataset a config with it asks for."""
    from spade.data.fingerprint import settings_fingerprint, shaping_settings

    recorded = {"window": {"size_px": 64, "resolution_m": 0.1}, "workers": 1, "seed": 0}
    asked = {**recorded, "workers": 8, "states_per_task": 8, "progress": True}
    assert shaping_settings(asked) == shaping_settings(recorded)
    assert settings_fingerprint(asked) == settings_fingerprint(recorded)
    assert settings_fingerprint({**recorded, "seed": 1}) != settings_fingerprint(recorded)


@pytest.mark.parametrize("name,row", [("waypoints", 3), ("pose", 1)])
def test_poisoned_values_are_refused_even_with_their_checksums_recomputed(tmp_path: Path, name: str, row: int) -> None:
    """Once, NaN in a polyline, checksums recomputed, loaded and scored as no error at all; now refused."""
    import hashlib

    root = tmp_path / "ds"
    write_synthetic(root, n=6)
    path = root / f"{name}.bin"
    manifest = json.loads((root / "manifest.json").read_text())
    values = np.fromfile(path, dtype="<f4").reshape(6, -1)
    values[row, 0] = np.nan
    values.tofile(path)
    manifest["files"][name]["sha256"] = hashlib.sha256(path.read_bytes()).hexdigest()
    from spade.data.format import MANIFEST_CHECKSUM, manifest_checksum

    manifest[MANIFEST_CHECKSUM] = manifest_checksum(manifest)  # the arrays' own checks must refuse it
    (root / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(DatasetError, match=rf"instance {row} holds NaN or inf") as info:
        PathDataset(root)
    assert str(path) in str(info.value)
