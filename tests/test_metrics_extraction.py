"""Path extraction on hand-drawn L and U masks, with gaps, spurs and blobs."""

from __future__ import annotations

import numpy as np
import pytest
from skimage.draw import disk

from spade.metrics.extraction import extract_path
from spade.metrics.geometry import polyline_ape
from spade.metrics.synthetic import rasterise_polyline

# '#' path, 'S' start (on the path), 'G' goal (on the path), '*' a blob or spur pixel (also predicted).
L_ART = [
    "....................",
    "..S#########........",
    "...........#........",
    "...........#........",
    "...........#........",
    "...........#........",
    "...........#........",
    "...........#........",
    "...........G........",
    "....................",
]
L_TRUTH = np.array([[2.0, 1.0], [11.0, 1.0], [11.0, 8.0]])

U_ART = [
    "......................",
    "..S##########.........",
    "............#.........",
    "............#.........",
    "............#.........",
    "............#.........",
    "..G##########.........",
    "......................",
]
U_TRUTH = np.array([[2.0, 1.0], [12.0, 1.0], [12.0, 6.0], [2.0, 6.0]])


def draw(art: list[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(probability image, start disc, goal disc) from ASCII art."""
    grid = np.array([list(row) for row in art])
    prob = np.isin(grid, list("#SG*")).astype(np.float32)
    markers = []
    for ch in "SG":
        (r,), (c,) = np.nonzero(grid == ch)
        m = np.zeros(grid.shape, dtype=np.float32)
        m[disk((r, c), 1.5, shape=grid.shape)] = 1.0
        markers.append(m)
    return prob, markers[0], markers[1]


def edit(art: list[str], x: int, y: int, ch: str) -> list[str]:
    rows = list(art)
    rows[y] = rows[y][:x] + ch + rows[y][x + 1 :]
    return rows


def pixel_set(pixels: np.ndarray) -> set[tuple[int, int]]:
    return {(int(x), int(y)) for x, y in np.rint(pixels)}


@pytest.mark.parametrize("art, truth", [(L_ART, L_TRUTH), (U_ART, U_TRUTH)], ids=["L", "U"])
def test_clean_shapes_are_ordered_from_start_to_goal(art: list[str], truth: np.ndarray) -> None:
    prob, start, goal = draw(art)
    res = extract_path(prob, start, goal, num_points=20)
    assert res.ok and res.reached_goal
    assert tuple(res.pixels[0]) == tuple(truth[0]) and tuple(res.pixels[-1]) == tuple(truth[-1])
    # Passes every corner (8-connected shortest paths may cut a corner pixel diagonally).
    gaps = np.linalg.norm(truth[:, None, :] - res.pixels[None, :, :], axis=2).min(axis=1)
    assert gaps.max() <= 1.0
    assert polyline_ape(res.points, truth) < 0.3  # two cut corner pixels in a tiny U
    # Reversing start and goal reverses the polyline.
    back = extract_path(prob, goal, start, num_points=20)
    np.testing.assert_allclose(back.points, res.points[::-1], atol=1e-9)


def test_gap_is_bridged_up_to_max_gap_and_cuts_otherwise() -> None:
    art = edit(edit(L_ART, 11, 4, "."), 11, 5, ".")  # a 2-pixel gap in the L's second leg
    prob, start, goal = draw(art)
    bridged = extract_path(prob, start, goal, num_points=20, max_gap=2)
    assert bridged.reached_goal and polyline_ape(bridged.points, L_TRUTH) < 0.2
    cut = extract_path(prob, start, goal, num_points=20, max_gap=0)
    assert cut.ok and not cut.reached_goal
    assert tuple(cut.pixels[-1]) == (11.0, 3.0)  # the farthest pixel reachable from the start
    assert polyline_ape(cut.points, L_TRUTH) > 2.0
    wide = edit(edit(art, 11, 3, "."), 11, 6, ".")  # a 4-pixel gap is not bridged by default
    assert not extract_path(*draw(wide), num_points=20).reached_goal


def test_spurs_are_not_followed() -> None:
    art = L_ART
    for x in (12, 13, 14):  # overshoot past the corner
        art = edit(art, x, 1, "*")
    for y in (2, 3, 4):  # a diagonal branch off the first segment
        art = edit(art, 5 + y, y, "*")
    prob, start, goal = draw(art)
    res = extract_path(prob, start, goal, num_points=20)
    assert res.reached_goal
    assert not any(x > 11 for x, _ in pixel_set(res.pixels))
    assert polyline_ape(res.points, L_TRUTH) < 0.3


def test_blobs_are_ignored_and_a_broken_path_keeps_the_start_part() -> None:
    art = L_ART
    for x in range(14, 18):  # a 4 x 2 blob far from the path
        for y in (6, 7):
            art = edit(art, x, y, "*")
    prob, start, goal = draw(art)
    res = extract_path(prob, start, goal, num_points=20)
    assert res.reached_goal and polyline_ape(res.points, L_TRUTH) < 0.2
    assert not any(x >= 14 for x, _ in pixel_set(res.pixels))


def test_path_not_touching_the_start_uses_the_nearest_component() -> None:
    art = L_ART
    for x in (2, 3, 4, 5):
        art = edit(art, x, 1, ".")  # the path now begins 4 px after the start
    art = edit(art, 2, 1, "S")
    prob, start, goal = draw(art)
    prob[1, 2] = 0.0  # the start pixel itself is not predicted
    res = extract_path(prob, start, goal, num_points=20, max_gap=0)
    assert res.ok and res.reached_goal
    assert tuple(res.pixels[0]) == (6.0, 1.0)


def test_wrong_way_prediction_ends_at_the_farthest_pixel() -> None:
    prob = np.zeros((20, 20), np.float32)
    prob[10, 10:19] = 1.0  # goes right from the start
    start, goal = np.array([10.0, 10.0]), np.array([1.0, 10.0])  # goal on the left
    res = extract_path(prob, start, goal, num_points=5)
    assert res.ok and not res.reached_goal
    np.testing.assert_allclose(res.points[[0, -1]], [[10, 10], [18, 10]])


def test_thick_drawn_shapes_follow_the_centre_line() -> None:
    truth = np.array([[6.0, 8.0], [40.0, 8.0], [40.0, 30.0], [10.0, 30.0]])
    prob = rasterise_polyline(truth, (48, 48), width=3).astype(np.float32)
    res = extract_path(prob * 0.9, truth[0], truth[-1], num_points=40)
    assert res.reached_goal
    assert polyline_ape(res.points, truth) < 0.5


def test_failures_are_reported() -> None:
    start, goal = np.array([2.0, 2.0]), np.array([8.0, 8.0])
    empty = extract_path(np.full((12, 12), 0.49), start, goal, num_points=8)
    assert not empty.ok and empty.failure == "empty" and empty.points is None
    dot = np.zeros((12, 12))
    dot[2, 2] = 1.0
    assert extract_path(dot, start, goal, num_points=8).failure == "too_short"
    # The threshold is configurable.
    assert extract_path(np.full((12, 12), 0.49), start, goal, num_points=8, threshold=0.4).ok


def test_bad_inputs_name_the_problem() -> None:
    prob = np.ones((8, 8))
    with pytest.raises(ValueError, match="start channel is empty"):
        extract_path(prob, np.zeros((8, 8)), np.array([1.0, 1.0]), num_points=4)
    with pytest.raises(ValueError, match="num_points"):
        extract_path(prob, np.array([1.0, 1.0]), np.array([5.0, 5.0]), num_points=1)
    with pytest.raises(ValueError, match="2-D"):
        extract_path(np.ones((1, 8, 8)), np.array([1.0, 1.0]), np.array([5.0, 5.0]), num_points=4)
