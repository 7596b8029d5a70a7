"""Tests for spade.maps: the occupancy grid, resampling, analysis and procedural maps."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from spade.maps import (
    FREE,
    GENERATORS,
    OCCUPIED,
    UNKNOWN,
    OccupancyMap,
    clear_square_fits,
    generate_map,
    largest_free_component,
    load_ros_map,
    max_clear_square_m,
    save_ros_map,
    traversable_mask,
)

SMALL = {"width_m": 16.0, "height_m": 16.0, "resolution": 0.1}


# ------------------------------------------------------------------------------------------ OccupancyMap
def test_world_pixel_conversion_matches_ros_convention() -> None:
    m = OccupancyMap(np.ones((4, 6), np.uint8), 0.5, (-1.0, 2.0, 0.0), "t")
    # Bottom-left pixel (row H-1, col 0) has its centre half a cell from the origin.
    np.testing.assert_allclose(m.pixel_to_world(np.array([0.0, 3.0])), [-0.75, 2.25])
    # Top-right pixel.
    np.testing.assert_allclose(m.pixel_to_world(np.array([5.0, 0.0])), [1.75, 3.75])
    pts = np.random.default_rng(0).uniform(-5, 5, size=(3, 7, 2))
    np.testing.assert_allclose(m.pixel_to_world(m.world_to_pixel(pts)), pts, atol=1e-12)
    np.testing.assert_allclose(m.world_to_pixel(np.array([[-1.0, 2.0]])), [[-0.5, 3.5]])


def test_conversion_refuses_rotated_origin() -> None:
    m = OccupancyMap(np.ones((4, 4), np.uint8), 0.05, (0.0, 0.0, 0.3))
    with pytest.raises(ValueError, match="yaw"):
        m.world_to_pixel(np.zeros(2))


def test_encoded_fractions_and_free_mask() -> None:
    grid = np.array([[UNKNOWN, FREE, OCCUPIED, FREE]], np.uint8)
    m = OccupancyMap(grid, 0.05)
    enc = m.encoded()
    assert enc.dtype == np.float32
    np.testing.assert_array_equal(enc, [[0.0, 0.5, 1.0, 0.5]])
    assert m.fractions() == {"occupied": 0.25, "free": 0.5, "unknown": 0.25}
    np.testing.assert_array_equal(m.free_mask(), [[False, True, False, True]])


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"grid": np.full((3, 3), 7, np.uint8)}, "outside the codes"),
        ({"grid": np.zeros((3,), np.uint8)}, "2D"),
        ({"resolution": 0.0}, "resolution"),
        ({"resolution": float("nan")}, "resolution"),
        ({"origin": (0.0, 0.0)}, "origin"),
    ],
)
def test_occupancy_map_validation(kwargs: dict, match: str) -> None:
    args = {"grid": np.zeros((3, 3), np.uint8), "resolution": 0.05, "origin": (0.0, 0.0, 0.0)}
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        OccupancyMap(**args)


# ------------------------------------------------------------------------------------------ resampling
@pytest.mark.parametrize("source, target", [(0.02, 0.05), (0.05, 0.2), (0.01, 0.05), (0.05, 0.07)])
@pytest.mark.parametrize("axis", [0, 1])
def test_downsampling_keeps_one_pixel_wall(source: float, target: float, axis: int) -> None:
    for pos in range(0, 17):
        grid = np.full((40, 40), FREE, np.uint8)
        if axis == 0:
            grid[pos, :] = OCCUPIED
        else:
            grid[:, pos] = OCCUPIED
        small = OccupancyMap(grid, source).resampled(target)
        # The wall still cuts the map: every row (column) of the coarse grid holds an occupied cell.
        assert (small.grid == OCCUPIED).any(axis=axis).all(), (source, target, axis, pos)
        # And it is not thickened beyond one target cell.
        assert (small.grid == OCCUPIED).any(axis=1 - axis).sum() == 1


def test_downsampling_size_origin_and_majority_rule() -> None:
    grid = np.full((1504, 1536), FREE, np.uint8)
    m = OccupancyMap(grid, 0.02, (-10.0, -20.24, 0.0), "w")
    small = m.resampled(0.05)
    assert small.grid.shape == (602, 615)  # every source pixel centre lies in a target cell
    assert small.origin == m.origin and small.resolution == 0.05

    # Factor 4 blocks: 2 free + 2 unknown -> free (ties go to free), 1 free + 3 unknown -> unknown.
    g = np.zeros((4, 8), np.uint8)
    g[:, :4] = np.array([FREE, FREE, UNKNOWN, UNKNOWN])[:, None]
    g[:, 4:] = np.array([FREE, UNKNOWN, UNKNOWN, UNKNOWN])[:, None]
    out = OccupancyMap(g, 0.05).resampled(0.2).grid
    np.testing.assert_array_equal(out, [[FREE, UNKNOWN]])


def test_resampling_keeps_lower_left_corner() -> None:
    grid = np.full((10, 10), FREE, np.uint8)
    grid[-1, 0] = OCCUPIED  # bottom-left pixel, touching the origin
    m = OccupancyMap(grid, 0.05, (1.0, 2.0, 0.0))
    for res in (0.15, 0.02):
        r = m.resampled(res)
        assert r.grid[-1, 0] == OCCUPIED
        # The obstacle is at the same world position.
        np.testing.assert_allclose(r.pixel_to_world(np.array([0.0, r.height - 1.0])), [1.0 + res / 2, 2.0 + res / 2])


def test_upsampling_is_nearest_neighbour() -> None:
    rng = np.random.default_rng(1)
    grid = rng.integers(0, 3, size=(7, 9)).astype(np.uint8)
    m = OccupancyMap(grid, 0.1)
    up = m.resampled(0.05)
    assert up.grid.shape == (14, 18)
    np.testing.assert_array_equal(up.grid, np.kron(grid, np.ones((2, 2), np.uint8)))
    back = up.resampled(0.1)
    np.testing.assert_array_equal(back.grid, grid)
    assert m.resampled(0.1).grid is not m.grid


@pytest.mark.parametrize("bad", [0.0, -0.05, float("inf"), "x"])
def test_resampled_rejects_bad_resolution(bad: object) -> None:
    with pytest.raises(ValueError, match="resolution"):
        OccupancyMap(np.ones((4, 4), np.uint8), 0.05).resampled(bad)  # type: ignore[arg-type]


# ------------------------------------------------------------------------------------------ analysis
def test_traversable_mask_and_clear_square() -> None:
    grid = np.full((40, 60), FREE, np.uint8)
    grid[0, :] = grid[-1, :] = grid[:, 0] = grid[:, -1] = OCCUPIED
    grid[:, 30] = OCCUPIED  # two rooms...
    grid[18:22, 30] = FREE  # ... joined by a 4-px door
    m = OccupancyMap(grid, 0.1)
    trav = traversable_mask(m, 0.15)  # 1.5 px: cells at distance >= 2 px from any obstacle
    assert not trav[1, 5] and trav[2, 5]
    assert trav[20, 30] and not trav[17, 30]
    comp = largest_free_component(m, 0.15)
    assert comp[5, 5] and comp[5, 50]  # one component through the door
    assert not largest_free_component(m, 0.25)[20, 30]  # 2.5 px radius does not pass a 4 px door
    # Left room: traversable rows 2..37 and columns 2..28 -> the largest square is 27 px.
    assert clear_square_fits(trav, 27) and not clear_square_fits(trav, 28)
    assert max_clear_square_m(m, 0.15) == pytest.approx(2.7)


# ------------------------------------------------------------------------------------------ procedural
@pytest.mark.parametrize("kind", sorted(GENERATORS))
def test_generator_is_deterministic(kind: str) -> None:
    a = generate_map(kind, 7, **SMALL)
    b = generate_map(kind, 7, **SMALL)
    c = generate_map(kind, 8, **SMALL)
    assert a.grid.tobytes() == b.grid.tobytes() and a.origin == b.origin
    assert a.grid.tobytes() != c.grid.tobytes()
    assert a.name == f"{kind}_7"
    assert a.grid.shape == (160, 160) and a.resolution == 0.1


@pytest.mark.parametrize("kind", sorted(GENERATORS))
def test_generator_looks_like_a_slam_map(kind: str) -> None:
    m = generate_map(kind, 3)
    assert m.resolution == 0.05
    assert 20.0 <= m.size_m[0] <= 30.0 and 20.0 <= m.size_m[1] <= 30.0
    g = m.grid
    # Unknown all around the building.
    assert (g[0] == UNKNOWN).all() and (g[-1] == UNKNOWN).all()
    assert (g[:, 0] == UNKNOWN).all() and (g[:, -1] == UNKNOWN).all()
    fr = m.fractions()
    assert fr["free"] > 0.5 and 0.02 < fr["occupied"] < 0.2 and 0.05 < fr["unknown"] < 0.45
    # Unknown speckles / hidden obstacle cores inside the building, not only the outer border.
    labels, n = ndimage.label(g == UNKNOWN)
    border = set(np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))) - {0}
    assert n - len(border) >= 10
    # Ragged, not ruler-straight obstacle edges: obstacle cells with exactly one obstacle 4-neighbour (spurs).
    occ = g == OCCUPIED
    neighbours = ndimage.convolve(occ.astype(int), np.array([[0, 1, 0], [1, 0, 1], [0, 1, 0]]), mode="constant")
    assert (occ & (neighbours == 1)).sum() > 50


@pytest.mark.parametrize("kind", sorted(GENERATORS))
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_generated_free_space_holds_6m_manoeuvres(kind: str, seed: int) -> None:
    """The robot (radius 0.22 m) reaches almost all free space, and its largest reachable region holds a 6 m x 6 m
    square, so L and U sketches of 6 m legs can be placed and driven there."""
    m = generate_map(kind, seed)
    trav = traversable_mask(m, 0.22)
    comp = largest_free_component(m, 0.22)
    assert comp.sum() >= 0.95 * trav.sum()
    assert max_clear_square_m(m, 0.22) >= 6.0


def test_generate_map_rejects_bad_input() -> None:
    with pytest.raises(ValueError, match="unknown map kind"):
        generate_map("castle", 0)
    with pytest.raises(ValueError, match="width_m"):
        generate_map("hall", 0, width_m=8.0)
    with pytest.raises(ValueError, match="unknown parameters"):
        generate_map("hall", 0, colour=1.0)
    with pytest.raises(ValueError, match="seed"):
        generate_map("office", -1)
    with pytest.raises(ValueError, match="resolution"):
        generate_map("office", 0, resolution=0.0)


@pytest.mark.parametrize("kind", sorted(GENERATORS))
def test_procedural_save_load_roundtrip(kind: str, tmp_path) -> None:
    m = generate_map(kind, 11, **SMALL)
    loaded = load_ros_map(save_ros_map(m, tmp_path / f"{kind}.yaml"))
    np.testing.assert_array_equal(loaded.grid, m.grid)
    assert loaded.resolution == m.resolution and loaded.origin == m.origin
