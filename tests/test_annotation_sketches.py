"""Operators' own sketch files go through the same execution and instance pipeline."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from spade.annotate import annotate
from spade.annotation.sketch_file import SketchFileError, load_sketch_file
from factories import site_map
from annotation_support import check_dataset, small_cfg


def write_sketches(tmp_path: Path, scenarios: list[dict]) -> Path:
    path = tmp_path / "sketches.yaml"
    path.write_text(yaml.safe_dump({"map": "site.yaml", "scenarios": scenarios}))
    return path


L_SKETCH = {"shape": "L", "name": "dock_a", "waypoints": [[0.0, 1.0], [1.5, 1.0], [2.5, 1.0], [3.1, 1.3], [3.4, 2.0], [3.4, 3.0]]}
U_SKETCH = {"shape": "U", "waypoints": [[0.0, 6.0], [2.5, 6.0], [3.1, 6.3], [3.3, 6.8], [3.1, 7.3], [2.5, 7.6], [1.0, 7.6]]}


def test_sketch_file_becomes_a_dataset(tmp_path: Path) -> None:
    site_map(tmp_path, block=True)
    sketches = write_sketches(tmp_path, [L_SKETCH, U_SKETCH])
    annotate(small_cfg(tmp_path / "ds", sketches=str(sketches)))
    manifest = check_dataset(tmp_path / "ds", {"L", "U"}, 30.0)
    assert set(manifest["labels"]["scenario_id"]["values"]) == {"site/dock_a", "site/U000"}
    first = [s for s in manifest["extra"]["scenarios"] if s["scenario_id"] == "site/dock_a"][0]
    assert first["instances"] > 10 and first["deviation_m"] < 0.35


def test_rejected_sketch_is_counted_not_silently_dropped(tmp_path: Path) -> None:
    site_map(tmp_path, block=True)
    straight = {"shape": "U", "name": "not_a_u", "waypoints": [[0.0, 1.0], [4.0, 1.0]]}
    annotate(small_cfg(tmp_path / "ds", sketches=str(write_sketches(tmp_path, [L_SKETCH, straight]))))
    extra = json.loads((tmp_path / "ds" / "manifest.json").read_text())["extra"]
    assert extra["rejections"] == {"shape": 1}


def test_sketch_outside_the_map_names_the_extent(tmp_path: Path) -> None:
    site_map(tmp_path, block=True)
    bad = {"shape": "L", "waypoints": [[0.0, 1.0], [15.0, 1.0], [15.0, 3.0]]}
    with pytest.raises(SketchFileError, match=r"waypoint #1 \(15\.00, 1\.00\) m lies outside .* x \[-2\.00, 10\.00\] m"):
        annotate(small_cfg(tmp_path / "ds", sketches=str(write_sketches(tmp_path, [bad]))))


def test_malformed_sketch_files(tmp_path: Path) -> None:
    site_map(tmp_path, block=True)
    with pytest.raises(SketchFileError, match="expected keys 'map' and 'scenarios'"):
        (tmp_path / "a.yaml").write_text("scenarios: []\n")
        load_sketch_file(tmp_path / "a.yaml")
    with pytest.raises(ValueError, match="unknown shape 'Z'"):
        load_sketch_file(write_sketches(tmp_path, [{"shape": "Z", "waypoints": [[0, 0], [1, 1]]}]))
    with pytest.raises(SketchFileError, match=r"\[x, y\] pairs"):
        load_sketch_file(write_sketches(tmp_path, [{"shape": "L", "waypoints": [[0, 0, 1]]}]))
