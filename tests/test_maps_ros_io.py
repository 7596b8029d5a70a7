"""Tests for spade.maps.ros_io: Nav2 map_server semantics, save/load round trips, errors and the real maps."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image

from spade.maps import FREE, OCCUPIED, UNKNOWN, MapFormatError, OccupancyMap, load_ros_map, save_ros_map

BASE_YAML = {
    "image": "m.png",
    "resolution": 0.05,
    "origin": [-1.5, 2.25, 0.0],
    "negate": 0,
    "occupied_thresh": 0.65,
    "free_thresh": 0.196,
}


def write_map(tmp_path: Path, picture: Image.Image | bytes | None, name: str = "m.png", **overrides) -> Path:
    """Write an image (or raw bytes) and a yaml that names it; ``overrides`` edit the yaml (None drops a key)."""
    if isinstance(picture, Image.Image):
        picture.save(tmp_path / name)
    elif isinstance(picture, bytes):
        (tmp_path / name).write_bytes(picture)
    doc = dict(BASE_YAML, image=name)
    for key, value in overrides.items():
        if value is None:
            doc.pop(key, None)
        else:
            doc[key] = value
    path = tmp_path / "m.yaml"
    path.write_text(yaml.safe_dump(doc), encoding="utf-8")
    return path


def grey(values: list[list[int]]) -> Image.Image:
    return Image.fromarray(np.array(values, dtype=np.uint8))


# ------------------------------------------------------------------------------------------ semantics
def test_trinary_grey_thresholds_and_metadata(tmp_path: Path) -> None:
    # p = 1 - v/255: 0 -> 1.0, 89 -> 0.651, 90 -> 0.647, 205 -> 0.196 (just above), 206 -> 0.192, 254, 255.
    path = write_map(tmp_path, grey([[0, 89, 90, 205, 206, 254, 255]]))
    m = load_ros_map(path)
    np.testing.assert_array_equal(m.grid, [[OCCUPIED, OCCUPIED, UNKNOWN, UNKNOWN, FREE, FREE, FREE]])
    assert m.resolution == 0.05 and m.origin == (-1.5, 2.25, 0.0) and m.name == "m"
    assert m.costs is None


def test_thresholds_are_inclusive(tmp_path: Path) -> None:
    # Nav2: occupied if p >= occupied_thresh, free if p <= free_thresh (black p=1.0, white p=0.0).
    path = write_map(tmp_path, grey([[0, 128, 255]]), occupied_thresh=1.0, free_thresh=0.0)
    np.testing.assert_array_equal(load_ros_map(path).grid, [[OCCUPIED, UNKNOWN, FREE]])


def test_negate_swaps_black_and_white(tmp_path: Path) -> None:
    path = write_map(tmp_path, grey([[0, 128, 255]]), negate=1)
    np.testing.assert_array_equal(load_ros_map(path).grid, [[FREE, UNKNOWN, OCCUPIED]])
    path = write_map(tmp_path, grey([[0, 128, 255]]), negate=True)
    np.testing.assert_array_equal(load_ros_map(path).grid, [[FREE, UNKNOWN, OCCUPIED]])


def test_colour_images_use_luma_not_the_channel_mean(tmp_path: Path) -> None:
    # Green: luma 150 (p 0.41, unknown) but mean 85 (p 0.67, occupied).
    # Yellow: luma 226 (p 0.11, free) but mean 170 (p 0.33, unknown).
    rgb = np.array([[[0, 255, 0], [255, 255, 0], [0, 0, 0], [255, 255, 255]]], dtype=np.uint8)
    path = write_map(tmp_path, Image.fromarray(rgb))
    np.testing.assert_array_equal(load_ros_map(path).grid, [[UNKNOWN, FREE, OCCUPIED, FREE]])


def test_alpha_below_255_is_unknown(tmp_path: Path) -> None:
    rgba = np.array(
        [[[255, 255, 255, 255], [255, 255, 255, 254], [0, 0, 0, 255], [0, 0, 0, 0], [0, 255, 0, 255]]], dtype=np.uint8
    )
    path = write_map(tmp_path, Image.fromarray(rgba))
    np.testing.assert_array_equal(load_ros_map(path).grid, [[FREE, UNKNOWN, OCCUPIED, UNKNOWN, UNKNOWN]])
    # Grey + alpha ("LA") as well, and in scale mode too.
    la = np.array([[[255, 255], [255, 100], [0, 255]]], dtype=np.uint8)
    path = write_map(tmp_path, Image.fromarray(la, mode="LA"), mode="scale")
    m = load_ros_map(path)
    np.testing.assert_array_equal(m.grid, [[FREE, UNKNOWN, OCCUPIED]])
    np.testing.assert_array_equal(m.costs, [[0, -1, 100]])


def test_palette_transparency_is_unknown(tmp_path: Path) -> None:
    img = Image.fromarray(np.array([[0, 1, 2]], dtype=np.uint8), mode="P")
    img.putpalette([255, 255, 255, 0, 0, 0, 255, 255, 255] + [0] * (256 * 3 - 9))
    img.info["transparency"] = 2
    path = write_map(tmp_path, None)
    img.save(tmp_path / "m.png", transparency=2)
    np.testing.assert_array_equal(load_ros_map(path).grid, [[FREE, OCCUPIED, UNKNOWN]])


def test_scale_mode_keeps_costs(tmp_path: Path) -> None:
    values = [0, 50, 128, 180, 255]
    path = write_map(tmp_path, grey([values]), mode="scale")
    m = load_ros_map(path)
    p = 1.0 - np.array(values) / 255.0
    between = (p > 0.196) & (p < 0.65)
    expected = np.where(p >= 0.65, 100, np.where(p <= 0.196, 0, np.floor((p - 0.196) / (0.65 - 0.196) * 100 + 0.5)))
    assert between.sum() == 2  # 128 and 180 are in-between grey levels
    np.testing.assert_array_equal(m.costs, [expected.astype(np.int8)])
    # Nav2 costmap StaticLayer (trinary_costmap): below lethal (100) is free, -1 unknown.
    np.testing.assert_array_equal(m.grid, [[OCCUPIED, OCCUPIED, FREE, FREE, FREE]])
    lower = load_ros_map(path, lethal_threshold=50)
    np.testing.assert_array_equal(lower.grid, [[OCCUPIED, OCCUPIED, OCCUPIED, FREE, FREE]])


def test_raw_mode_takes_values_directly(tmp_path: Path) -> None:
    path = write_map(tmp_path, grey([[0, 50, 99, 100, 101, 255]]), mode="raw", negate=1)
    m = load_ros_map(path)
    np.testing.assert_array_equal(m.costs, [[0, 50, 99, 100, -1, -1]])
    np.testing.assert_array_equal(m.grid, [[FREE, FREE, FREE, OCCUPIED, UNKNOWN, UNKNOWN]])


def test_image_path_relative_to_yaml_or_absolute(tmp_path: Path) -> None:
    (tmp_path / "img").mkdir()
    grey([[0, 255]]).save(tmp_path / "img" / "x.pgm")
    path = write_map(tmp_path, None, image="img/x.pgm")
    np.testing.assert_array_equal(load_ros_map(path).grid, [[OCCUPIED, FREE]])
    path = write_map(tmp_path, None, image=str(tmp_path / "img" / "x.pgm"))
    np.testing.assert_array_equal(load_ros_map(path).grid, [[OCCUPIED, FREE]])


def test_missing_mode_means_trinary_and_16_bit_images_are_scaled(tmp_path: Path) -> None:
    img = Image.fromarray(np.array([[0, 65535, 32896]], dtype=np.uint16))
    path = write_map(tmp_path, img, name="m16.png", mode=None)
    np.testing.assert_array_equal(load_ros_map(path).grid, [[OCCUPIED, FREE, UNKNOWN]])


# ------------------------------------------------------------------------------------------ save / load
@pytest.mark.parametrize("fmt", ["pgm", "png"])
def test_save_load_is_exact(tmp_path: Path, fmt: str) -> None:
    grid = np.random.default_rng(3).integers(0, 3, size=(23, 31)).astype(np.uint8)
    m = OccupancyMap(grid, 0.0123456789, (-12.345678901234, 3.3e-05, 0.25), "odd")
    path = save_ros_map(m, tmp_path / "out" / "odd.yaml", image_format=fmt)
    raw = np.asarray(Image.open(path.with_suffix(f".{fmt}")))
    assert set(np.unique(raw)) <= {0, 205, 254}
    loaded = load_ros_map(path)
    np.testing.assert_array_equal(loaded.grid, grid)
    assert loaded.resolution == m.resolution and loaded.origin == m.origin and loaded.name == "odd"


def test_save_rejects_bad_arguments(tmp_path: Path) -> None:
    m = OccupancyMap(np.ones((2, 2), np.uint8), 0.05)
    with pytest.raises(ValueError, match="yaml"):
        save_ros_map(m, tmp_path / "m.pgm")
    with pytest.raises(ValueError, match="image_format"):
        save_ros_map(m, tmp_path / "m.yaml", image_format="jpg")


# ------------------------------------------------------------------------------------------ errors
ERROR_CASES = {
    "no image key": ({"image": None}, "no 'image' key"),
    "empty image": ({"image": ""}, "'image' must be a non-empty"),
    "missing image": ({"image": "nothere.pgm"}, "does not exist"),
    "zero resolution": ({"resolution": 0}, "'resolution' must be > 0"),
    "negative resolution": ({"resolution": -0.05}, "'resolution' must be > 0"),
    "text resolution": ({"resolution": "fine"}, "'resolution' must be a number"),
    "unknown mode": ({"mode": "fancy"}, "unknown map mode"),
    "occupied above 1": ({"occupied_thresh": 1.5}, r"must lie in \[0, 1\]"),
    "free below 0": ({"free_thresh": -0.1}, r"must lie in \[0, 1\]"),
    "free >= occupied": ({"free_thresh": 0.7}, "must be smaller than occupied_thresh"),
    "short origin": ({"origin": [0.0, 0.0]}, "'origin' must be a list of 3"),
    "no negate": ({"negate": None}, "no 'negate' key"),
    "no occupied_thresh": ({"occupied_thresh": None}, "no 'occupied_thresh' key"),
}


@pytest.mark.parametrize("case", sorted(ERROR_CASES))
def test_bad_yaml_raises_map_format_error_naming_the_file(tmp_path: Path, case: str) -> None:
    overrides, match = ERROR_CASES[case]
    path = write_map(tmp_path, grey([[0, 255]]), **overrides)
    with pytest.raises(MapFormatError, match=match) as info:
        load_ros_map(path)
    assert str(path) in str(info.value) and "Fix:" in str(info.value)


def test_unreadable_image_raises(tmp_path: Path) -> None:
    path = write_map(tmp_path, b"this is not an image", name="broken.pgm")
    with pytest.raises(MapFormatError, match="cannot read the image") as info:
        load_ros_map(path)
    assert str(path) in str(info.value)


@pytest.mark.parametrize("text", ["image: [unclosed\nresolution: 0.05\n", "- just\n- a list\n", ""])
def test_malformed_yaml_raises(tmp_path: Path, text: str) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(MapFormatError) as info:
        load_ros_map(path)
    assert str(path) in str(info.value)


def test_missing_yaml_raises(tmp_path: Path) -> None:
    with pytest.raises(MapFormatError, match="does not exist"):
        load_ros_map(tmp_path / "none.yaml")


# ------------------------------------------------------------------------------------------ real maps
def independent_fractions(yaml_path: Path) -> dict[str, float]:
    """Nav2 trinary classification written from scratch: float64 Rec.601 luma, inclusive thresholds, alpha."""
    doc = yaml.safe_load(yaml_path.read_text())
    arr = np.asarray(Image.open(yaml_path.parent / doc["image"])).astype(np.float64)
    alpha = None
    if arr.ndim == 3:
        if arr.shape[2] == 4:
            alpha = arr[..., 3]
        v = np.floor(arr[..., 0] * 0.299 + arr[..., 1] * 0.587 + arr[..., 2] * 0.114 + 0.5)
    else:
        v = arr
    p = v / 255.0 if doc.get("negate", 0) else (255.0 - v) / 255.0
    occ = p >= doc["occupied_thresh"]
    free = (p <= doc["free_thresh"]) & ~occ
    if alpha is not None:
        occ &= alpha >= 255
        free &= alpha >= 255
    n = p.size
    return {"occupied": occ.sum() / n, "free": free.sum() / n, "unknown": 1.0 - (occ.sum() + free.sum()) / n}


def test_real_maps_load_with_nav2_fractions(maps_dir: Path) -> None:
    yamls = sorted(maps_dir.rglob("*.yaml"))
    assert yamls
    for path in yamls:
        m = load_ros_map(path)
        doc = yaml.safe_load(path.read_text())
        assert doc.get("mode", "trinary") == "trinary"
        with Image.open(path.parent / doc["image"]) as img:
            assert m.grid.shape == (img.height, img.width), path
        assert m.resolution == pytest.approx(doc["resolution"]) and m.origin == tuple(float(v) for v in doc["origin"])
        got, want = m.fractions(), independent_fractions(path)
        for key in want:
            assert got[key] == pytest.approx(want[key], abs=1e-3), (path.name, key, got, want)


def test_willow_garage_fractions(maps_dir: Path) -> None:
    path = maps_dir / "pal_maps" / "willow_garage.yaml"
    if not path.is_file():
        pytest.skip(f"{path} is not in SPADE_MAPS_DIR")
    fr = load_ros_map(path).fractions()
    assert fr["occupied"] == pytest.approx(0.042, abs=0.005)
    assert fr["free"] == pytest.approx(0.735, abs=0.005)
    assert fr["unknown"] == pytest.approx(0.224, abs=0.005)


def test_real_maps_save_load_roundtrip(maps_dir: Path, tmp_path: Path) -> None:
    for i, path in enumerate(sorted(maps_dir.rglob("*.yaml"))):
        m = load_ros_map(path)
        loaded = load_ros_map(save_ros_map(m, tmp_path / f"{i}_{m.name}.yaml"))
        np.testing.assert_array_equal(loaded.grid, m.grid, err_msg=str(path))
        assert loaded.resolution == m.resolution and loaded.origin == m.origin


def test_real_warehouse_resampled_keeps_obstacles(maps_dir: Path) -> None:
    path = maps_dir / "aws-robomaker-small-warehouse-world" / "small_warehouse_002.yaml"
    if not path.is_file():
        pytest.skip(f"{path} is not in SPADE_MAPS_DIR")
    m = load_ros_map(path)
    small = m.resampled(0.05)
    assert small.grid.shape == (602, 615)
    # Every occupied source pixel lands in an occupied coarse cell: the one holding its centre, which lies at
    # (i + 0.5) * 0.02 m = (2i + 1) / 5 coarse cells from the lower-left corner (exact integer arithmetic).
    occ_rows, occ_cols = np.nonzero(m.grid == OCCUPIED)
    assert len(occ_rows) > 10_000
    col = (2 * occ_cols + 1) // 5
    row = small.height - 1 - (2 * (m.height - 1 - occ_rows) + 1) // 5
    assert (small.grid[row, col] == OCCUPIED).all()
    # The coarse map is not flooded with obstacles either.
    assert small.fractions()["occupied"] < 3.0 * m.fractions()["occupied"]
