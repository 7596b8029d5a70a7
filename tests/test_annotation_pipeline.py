"""End-to-end tests of the annotation tool on procedural and real maps (small windows, few instances)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from spade.annotate import annotate
from spade.annotation.pipeline import NotEnoughInstancesError
from spade.annotation.templates import UnknownShapeError
from spade.data import read_manifest
from annotation_support import check_dataset, small_cfg

ROOT = Path(__file__).resolve().parents[1]


def dataset_bytes(root: Path) -> dict:
    out = {p.name: p.read_bytes() for p in sorted(root.glob("*.bin"))}
    manifest = json.loads((root / "manifest.json").read_text())
    out["labels"] = json.dumps(manifest["labels"], sort_keys=True).encode()
    out["extra"] = json.dumps(manifest["extra"], sort_keys=True).encode()
    out["preview"] = (root / "preview.png").read_bytes()
    return out


def test_procedural_maps_give_sound_instances_and_manifest(tmp_path: Path) -> None:
    cfg = small_cfg(tmp_path / "ds", shape=["L", "U"], num_instances=120)
    summary = annotate(cfg)
    assert summary["instances"] == 120
    manifest = check_dataset(tmp_path / "ds", {"L", "U"}, cfg["execution"]["shape_tolerance_deg"])
    extra = manifest["extra"]
    assert extra["source"] == "templates" and extra["scenarios_accepted"] >= 2
    assert isinstance(extra["rejections"], dict) and set(extra["rejections_by_map"]) <= {"warehouse-s1", "office-s2"}
    ids = manifest["labels"]["scenario_id"]["values"]
    assert all(i.split("/")[0] in {"warehouse-s1", "office-s2"} for i in ids) and len(set(ids)) == len(ids)
    assert manifest["resolution"] == 0.1 and manifest["image_size"] == [64, 64]
    assert (tmp_path / "ds" / "preview.png").stat().st_size > 0


def test_same_seed_same_bytes_other_seed_other_bytes(tmp_path: Path) -> None:
    annotate(small_cfg(tmp_path / "a", seed=5))
    annotate(small_cfg(tmp_path / "b", seed=5))
    annotate(small_cfg(tmp_path / "c", seed=6))
    a, b, c = (dataset_bytes(tmp_path / n) for n in "abc")
    assert a == b
    assert a["path.bin"] != c["path.bin"]


def test_worker_count_never_changes_the_bytes(tmp_path: Path) -> None:
    annotate(small_cfg(tmp_path / "w1", workers=1, shape="U", num_instances=90))
    annotate(small_cfg(tmp_path / "w2", workers=2, shape="U", num_instances=90))
    assert dataset_bytes(tmp_path / "w1") == dataset_bytes(tmp_path / "w2")


def test_scenarios_spread_over_areas_of_each_map(tmp_path: Path) -> None:
    cfg = small_cfg(tmp_path / "ds", maps=["hall:3"], num_instances=200, shape="L")
    annotate(cfg)
    scen = json.loads((tmp_path / "ds" / "manifest.json").read_text())["extra"]["scenarios"]
    assert len(scen) >= 4 and all(s["map_id"] == "hall-s3" for s in scen)
    assert [s["scenario_id"] for s in scen][:3] == ["hall-s3/L000", "hall-s3/L001", "hall-s3/L002"][: len(scen)]


def test_map_where_no_sketch_fits_is_given_up_quickly(tmp_path: Path) -> None:
    from spade.maps import OccupancyMap, save_ros_map

    g = np.full((80, 80), 2, np.uint8)
    g[30:46, 30:46] = 1  # room for a goal, none for a sketch
    yaml_path = save_ros_map(OccupancyMap(g, 0.1, name="closet"), tmp_path / "closet.yaml")
    with pytest.raises(NotEnoughInstancesError, match=r"gave only 0 .* given up after 5 failures in a row: \['closet:L'\]"):
        annotate(small_cfg(tmp_path / "ds", maps=[str(yaml_path)], **{"scenario.max_failures": 5}))


def test_bad_inputs_fail_with_numbers(tmp_path: Path) -> None:
    with pytest.raises(UnknownShapeError, match="known shapes"):
        annotate(small_cfg(tmp_path / "x", shape="S"))
    with pytest.raises(NotEnoughInstancesError, match=r"num_instances=100000 .* gave only \d+"):
        annotate(small_cfg(tmp_path / "y", maps=["office:2"], num_instances=100000, **{"scenario.max_per_map": 2}))
    assert not (tmp_path / "y").exists()
    with pytest.raises(FileNotFoundError, match="neither an existing folder"):
        annotate(small_cfg(tmp_path / "z", maps=["no/such/map.yaml"]))


def test_map_too_cluttered_for_a_goal(tmp_path: Path) -> None:
    from spade.annotation.scenarios import NoFreeAreaError
    from spade.maps import OccupancyMap, save_ros_map

    g = np.full((80, 80), 2, np.uint8)
    g[30:40, 30:40] = 1  # 1 m square: 0.5 m clearance at best, a goal needs 0.655 m
    yaml_path = save_ros_map(OccupancyMap(g, 0.1, name="cell"), tmp_path / "cell.yaml")
    with pytest.raises(NoFreeAreaError, match=r"map 'cell' .* no free cell with 0\.66 m clearance"):
        annotate(small_cfg(tmp_path / "ds", maps=[str(yaml_path)]))


@pytest.mark.slow  # a python -m spade.annotate process; annotation runs in-process: the tests above
def test_cli_with_overrides_and_preview(tmp_path: Path) -> None:
    out = tmp_path / "cli"
    proc = subprocess.run(
        [sys.executable, "-m", "spade.annotate", "shape=U", "maps=[office:2]", "num_instances=20", "seed=1",
         f"out_dir={out}", "workers=1", "progress=false", "window.size_px=64", "window.resolution_m=0.1",
         f"hydra.run.dir={tmp_path / 'hydra'}"],
        cwd=ROOT, capture_output=True, text=True, timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    manifest = read_manifest(out)
    assert manifest.num_instances == 20 and (out / "preview.png").is_file()


@pytest.mark.parametrize("names", [["small_office", "maze"]])
def test_real_maps_give_sound_instances(tmp_path: Path, maps_dir: Path, names: list[str]) -> None:
    yamls = [str(p) for n in names for p in maps_dir.rglob(f"{n}.yaml")]
    assert len(yamls) == len(names)
    cfg = small_cfg(tmp_path / "real", maps=yamls, shape=["L", "U"], num_instances=120)
    annotate(cfg)
    manifest = check_dataset(tmp_path / "real", {"L", "U"}, cfg["execution"]["shape_tolerance_deg"])
    assert {m["map_id"] for m in manifest["extra"]["maps"]} == set(names)


@pytest.mark.slow  # 600 instances on every real map; two real maps: test_real_maps_give_sound_instances
def test_every_real_map_of_the_folder(tmp_path: Path, maps_dir: Path) -> None:
    cfg = small_cfg(tmp_path / "all", maps=str(maps_dir), shape=["L", "U"], num_instances=600, workers=2)
    annotate(cfg)
    manifest = check_dataset(tmp_path / "all", {"L", "U"}, cfg["execution"]["shape_tolerance_deg"])
    assert len(manifest["extra"]["maps"]) == len(list(maps_dir.rglob("*.yaml")))


@pytest.mark.slow  # 128 px, two workers; at 64 px: test_worker_count_never_changes_the_bytes
def test_same_seed_same_bytes_on_real_maps_at_full_size(tmp_path: Path, maps_dir: Path) -> None:
    yamls = [str(next(maps_dir.rglob("bookstore.yaml")))]
    for name, workers in (("a", 1), ("b", 2)):
        cfg = small_cfg(tmp_path / name, maps=yamls, num_instances=150, workers=workers, num_waypoints=64)
        cfg["window"].update(size_px=128, resolution_m=0.05)
        cfg["instances"]["spacing_m"] = 0.05
        annotate(cfg)
    assert dataset_bytes(tmp_path / "a") == dataset_bytes(tmp_path / "b")
    check_dataset(tmp_path / "a", {"L"}, 30.0)
