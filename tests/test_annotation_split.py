"""``split=area:PART`` / ``split=scenario:PART``: a training and a test set on one map that share nothing, refused
in one line when the settings are wrong, recorded in the manifest so that the two parts can be checked to belong
together (tiny windows and instance counts)."""

from __future__ import annotations

import json
import multiprocessing
import os
from pathlib import Path

import numpy as np
import pytest
from omegaconf import OmegaConf

from spade.annotate import annotate
from spade.annotation.split import (
    CROSSING,
    in_scenario_part,
    parse_split,
    read_split,
    split_pair_problems,
)
from spade.data.path_dataset import PathDataset
from spade.data.checks import settings_difference
from spade.data.datamodule import leaked_scenarios
from spade.data.fingerprint import NON_SHAPING_KEYS, settings_fingerprint, shaping_settings
from spade.config.annotate_checks import validate_annotate_config
from spade.utils.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]
SPLIT_KEYS = ("split", "split_fraction", "split_axis")


def tiny_cfg(out_dir: Path, **over) -> dict:
    """One map, L only, 64 px x 0.1 m/px windows, 40 instances in this process."""
    cfg = OmegaConf.to_container(OmegaConf.load(ROOT / "conf" / "annotate.yaml"), resolve=False)
    cfg.pop("defaults", None)
    cfg.pop("hydra", None)
    cfg.update(out_dir=str(out_dir), workers=1, progress=False, num_instances=40, num_waypoints=16,
               maps=["office:2"], shape="L", seed=0)
    cfg["window"].update(size_px=64, resolution_m=0.1)
    cfg["instances"]["spacing_m"] = 0.15
    cfg["preview"]["enabled"] = False
    cfg.update(over)
    return cfg


def world_points(ds: PathDataset, i: int) -> tuple[np.ndarray, dict]:
    """Instance ``i``'s remaining path (start first, goal last) in map metres, from its pose and window waypoints."""
    item = ds[i]
    x, y, yaw = (float(v) for v in item["pose"])
    wp = item["waypoints"].numpy().astype(np.float64)
    rx, ry = ds.frame["robot_px"]
    ahead, left = (ry - wp[:, 1]) * ds.resolution, (rx - wp[:, 0]) * ds.resolution  # heading up, left is left
    pts = np.stack([x + ahead * np.cos(yaw) - left * np.sin(yaw), y + ahead * np.sin(yaw) + left * np.cos(yaw)], 1)
    return pts, item


def turtlebot3_map() -> str:
    maps = os.environ.get("SPADE_MAPS_DIR")
    path = Path(maps or "/nonexistent") / "turtlebot3" / "turtlebot3_world.yaml"
    if not maps or not path.is_file():
        pytest.skip("SPADE_MAPS_DIR with turtlebot3/turtlebot3_world.yaml is not set")
    return str(path)


@pytest.fixture(scope="module")
def area_parts(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The training and the test part of office:2 split by area (default fraction and axis)."""
    root = tmp_path_factory.mktemp("area")
    for part in ("train", "test"):
        annotate(tiny_cfg(root / part, split=f"area:{part}"))
    return {part: root / part for part in ("train", "test")}


def check_on_side(root: Path) -> dict:
    """Every instance's start, goal and remaining path lie strictly on its part's side of the recorded line; the
    conversion to metres is checked too (start = pose, one goal per scenario)."""
    ds = PathDataset(root)
    record = ds.manifest.extra["split"]
    assert ds.manifest.generator["split"] == f"area:{record['part']}"
    goals: dict[str, list[np.ndarray]] = {}
    for i in range(len(ds)):
        pts, item = world_points(ds, i)
        assert np.allclose(pts[0], item["pose"][:2].numpy(), atol=1e-4)
        line = record["lines"][item["map_id"]]
        coord = pts[:, 0 if line["axis"] == "x" else 1]
        beyond = coord - line["at_m"] if record["part"] == "train" else line["at_m"] - coord
        assert (beyond < -1e-3).all(), (item["scenario_id"], float(beyond.max()), line)
        goals.setdefault(item["scenario_id"], []).append(pts[-1])
    assert len(goals) >= 2
    for sid, g in goals.items():  # every robot state of a scenario drives to the same goal
        assert np.ptp(np.array(g), axis=0).max() < 1e-3, sid
    return record


def test_area_split_keeps_every_instance_on_its_side(area_parts: dict[str, Path]) -> None:
    train, test = (check_on_side(area_parts[p]) for p in ("train", "test"))
    line = train["lines"]["office-s2"]
    assert train["fraction"] == 0.7 and train["axis"] == "auto" and line["axis"] == "x"  # office:2 is wider
    assert abs(line["train_share"] - 0.7) < 0.02
    assert split_pair_problems(train, test) == []
    # the test part's narrow side rejects scenarios that cross the line, counted like any other rejection
    extra = PathDataset(area_parts["test"]).manifest.extra
    assert extra["rejections"].get(CROSSING, 0) > 0
    assert extra["rejections_by_map"]["office-s2"][CROSSING] == extra["rejections"][CROSSING]
    ids = [set(PathDataset(area_parts[p]).labels("scenario_id")) for p in ("train", "test")]
    assert ids[0] and ids[1]


def test_area_split_on_a_real_map(tmp_path: Path) -> None:
    """turtlebot3_world (5 x 5 m of free space): split in halves, the test part's quarter would be too narrow."""
    yaml_path = turtlebot3_map()
    for part in ("train", "test"):
        annotate(tiny_cfg(tmp_path / part, maps=[yaml_path], split=f"area:{part}", split_fraction=0.5,
                          num_instances=30))
    records = [check_on_side(tmp_path / p) for p in ("train", "test")]
    assert split_pair_problems(*records) == []


def test_a_test_part_on_another_line_is_detected(area_parts: dict[str, Path], tmp_path: Path) -> None:
    annotate(tiny_cfg(tmp_path / "test", split="area:test", split_fraction=0.6))
    train, other = read_split(area_parts["train"]), read_split(tmp_path / "test")
    problems = split_pair_problems(train, other)
    assert any("fraction" in p for p in problems) and any("at_m" in p for p in problems)
    assert split_pair_problems(read_split(area_parts["test"]), train)  # parts swapped
    assert split_pair_problems(train, None) == ["the test set records no split (made without split=...)"]


@pytest.mark.skipif("fork" not in multiprocessing.get_all_start_methods(), reason="needs the fork start method")
def test_area_split_output_never_depends_on_the_workers(area_parts: dict[str, Path], tmp_path: Path) -> None:
    annotate(tiny_cfg(tmp_path / "w2", split="area:test", workers=2, states_per_task=3, start_method="fork"))
    for name in ("occupancy", "waypoints", "pose", "path"):
        a = (area_parts["test"] / f"{name}.bin").read_bytes()
        assert (tmp_path / "w2" / f"{name}.bin").read_bytes() == a, name
    assert read_split(tmp_path / "w2") == read_split(area_parts["test"])


def test_scenario_split_sets_share_no_scenario(tmp_path: Path) -> None:
    for part in ("train", "test"):
        annotate(tiny_cfg(tmp_path / part, maps=["warehouse:1"], split=f"scenario:{part}", num_instances=60))
    train, test = PathDataset(tmp_path / "train"), PathDataset(tmp_path / "test")
    ids = {p: set(ds.labels("scenario_id")) for p, ds in (("train", train), ("test", test))}
    assert ids["train"] and ids["test"] and not ids["train"] & ids["test"]
    split = {p: parse_split({"split": f"scenario:{p}"}) for p in ("train", "test")}
    for part, found in ids.items():
        for sid in found:
            index = int(sid.rsplit("/", 1)[1][1:])
            assert in_scenario_part(split[part], index) and not in_scenario_part(split[{"train": "test",
                                                                                         "test": "train"}[part]], index)
    assert not set(train.instance_digests()) & set(test.instance_digests())
    assert leaked_scenarios(train, test) == []
    records = [read_split(tmp_path / p) for p in ("train", "test")]
    assert records[0]["mode"] == "scenario" and split_pair_problems(*records) == []


def test_split_shapes_the_bytes_and_unset_changes_no_recorded_settings() -> None:
    """The split keys are shaping settings; left null they match a dataset recorded before they existed."""
    assert not set(SPLIT_KEYS) & NON_SHAPING_KEYS
    base = {"window": {"size_px": 64}, "seed": 0}
    unset = {**base, "split": None, "split_fraction": None, "split_axis": None}
    assert settings_difference(base, unset) == {}
    area = {**unset, "split": "area:train"}
    assert "split" in shaping_settings(area)
    assert settings_fingerprint(area) != settings_fingerprint({**area, "split": "area:test"})
    assert settings_fingerprint(area) != settings_fingerprint({**area, "split_fraction": 0.6})


def test_no_split_records_none(tmp_path: Path) -> None:
    annotate(tiny_cfg(tmp_path / "plain", num_instances=10))
    manifest = json.loads((tmp_path / "plain" / "manifest.json").read_text())
    assert "split" not in manifest["extra"] and read_split(tmp_path / "plain") is None
    assert all(manifest["generator"][k] is None for k in SPLIT_KEYS)


@pytest.mark.parametrize(("over", "names"), [
    ({"split": "area:tain"}, "split=area:tain"),
    ({"split": "areas:train"}, "split=areas:train"),
    ({"split": "train"}, "split=train"),
    ({"split": "area"}, "split=area"),
    ({"split": "area:train", "split_fraction": 1.0}, "split_fraction=1.0"),
    ({"split": "area:test", "split_fraction": 0}, "split_fraction=0"),
    ({"split": "scenario:test", "split_fraction": -0.5}, "split_fraction=-0.5"),
    ({"split": "area:train", "split_fraction": "half"}, "split_fraction=half"),
    ({"split": "area:train", "split_axis": "z"}, "split_axis=z"),
    ({"split": "scenario:train", "split_axis": "x"}, "split_axis=x"),
    ({"split_fraction": 0.5}, "split_fraction=0.5"),
])
def test_bad_split_values_are_refused_in_one_line_before_any_generation(tmp_path: Path, over: dict,
                                                                        names: str) -> None:
    cfg = tiny_cfg(tmp_path / "ds", **over)
    with pytest.raises(ConfigError) as caught:
        validate_annotate_config(cfg)
    message = str(caught.value)
    assert message.startswith(names) and "\n" not in message
    assert any(fix in message for fix in ("use split=", "e.g.", "remove split_"))
    with pytest.raises(ConfigError):  # annotate() refuses it too, before a map is loaded or a folder made
        annotate(cfg)
    assert not (tmp_path / "ds").exists()


def test_split_of_sketches_is_refused(tmp_path: Path) -> None:
    cfg = tiny_cfg(tmp_path / "ds", split="area:train", sketches=str(tmp_path / "s.yaml"))
    with pytest.raises(ConfigError, match=r"^split=area:train splits the scenarios drawn on maps="):
        parse_split(cfg)


def test_transfer_preset_keeps_its_own_split() -> None:
    assert parse_split({"split": "train", "transfer_splits": {"train": {}}}) is None


def test_the_data_module_refuses_a_test_part_of_another_split(area_parts: dict[str, Path], tmp_path: Path) -> None:
    """data=own with a training part and a test part cut on another line stops before training, naming the
    difference; the two parts of one split pass."""
    from spade.data import DatasetError
    from spade.data.datamodule import PathDataModule

    annotate(tiny_cfg(tmp_path / "other_test", split="area:test", split_fraction=0.6))
    good = PathDataModule(area_parts["train"], test_dir=area_parts["test"], batch_size=4)
    good.setup("test")
    bad = PathDataModule(area_parts["train"], test_dir=tmp_path / "other_test", batch_size=4)
    with pytest.raises(DatasetError, match=r"not the test part of .*split fraction: training set 0\.7, test set 0\.6"):
        bad.setup("test")
