"""Prediction pictures a person reads at a glance in MLflow's Artifacts tab: the legend at the
top, at most 900 px tall, the extracted path in a colour the heat map never takes, the worst panels from distinct
scenarios; run descriptions with centimetres to 0.1 cm."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from spade.training.visualize import EXTRACTED_COLOUR, MAX_HEIGHT_PX, TestRecords, prediction_grid

from factories import synthetic_instance


def _batch(n: int, size: int, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    items = [synthetic_instance(rng, size=size, k=16) for _ in range(n)]
    occ = np.stack([it["occupancy"] for it in items]).astype(np.float32) / 2
    state = torch.from_numpy(np.stack([occ, np.stack([it["start"] for it in items]),
                                       np.stack([it["goal"] for it in items])], axis=1).astype(np.float32))
    path = torch.from_numpy(np.stack([it["path"] for it in items])[:, None].astype(np.float32))
    wps = torch.from_numpy(np.stack([it["waypoints"] for it in items]))
    return {"state": state, "path": path, "waypoints": wps, "resolution": torch.full((n,), 0.1)}


@pytest.mark.parametrize("rows, size", [(4, 64), (4, 128), (8, 64), (1, 64)])
def test_pictures_are_at_most_900_px_tall_with_the_legend_on_top(rows: int, size: int) -> None:
    b = _batch(rows, size)
    picture = prediction_grid(b["state"], b["path"], b["path"] * 0.9, b["waypoints"], b["resolution"])
    height = picture.shape[0]
    assert height <= MAX_HEIGHT_PX, picture.shape
    legend = np.all(np.abs(picture.astype(int) - 0x77) <= 2, axis=2)  # the legend's grey box
    rows_with_legend = np.nonzero(legend.sum(axis=1) > picture.shape[1] // 4)[0]
    assert len(rows_with_legend) and rows_with_legend.max() < 0.12 * height + 30  # at the top, not the bottom


def test_the_extracted_path_is_drawn_in_a_colour_the_heat_map_never_takes() -> None:
    import matplotlib

    inferno = matplotlib.colormaps["inferno"](np.linspace(0, 1, 256))[:, :3]
    colour = np.array([int(EXTRACTED_COLOUR[k:k + 2], 16) / 255 for k in (1, 3, 5)])
    assert np.min(np.linalg.norm(inferno - colour, axis=1)) > 0.5
    b = _batch(2, 64)
    picture = prediction_grid(b["state"], b["path"], b["path"] * 0.9, b["waypoints"], b["resolution"])
    target = (colour * 255).round().astype(int)
    assert (np.abs(picture.astype(int) - target).sum(axis=2) < 40).sum() > 20  # the path is there, in that colour


def test_the_worst_panels_come_from_distinct_scenarios() -> None:
    records = TestRecords()
    b = _batch(8, 32)
    records.add({**b, "scenario_id": ["a", "a", "a", "a", "b", "c", "d", "e"]},
                torch.zeros_like(b["path"]))  # nothing predicted: every instance fails alike
    chosen: list[list[int]] = []
    records._grid = lambda indices, label: chosen.append(indices) or np.zeros((1, 1, 3), np.uint8)
    records.pictures(4)
    scenarios = [records.scenarios[i] for i in chosen[0]]
    assert len(scenarios) == 4 and len(set(scenarios)) == 4, scenarios


def test_run_description_figures_are_rounded_to_a_tenth_of_a_centimetre() -> None:
    from spade.tracking.descriptions import figures_table

    text = figures_table({"test/ape_cm": 10.1234, "test/baseline/straight/ape_cm": 25.0149, "test/hd19": 3.0})
    import re

    assert re.search(r"\|\s+10\.1 \|", text) and re.search(r"\|\s+25\.0 \|", text) and "10.12" not in text


def test_the_epoch_picture_shows_distinct_scenarios_in_wide_readable_panels() -> None:
    """Once, the per-epoch pictures were 180 x 900 px with about 64 px panels, the legend cut, and all eight
    rows from the same map window. Now: the first instance of each new scenario, in validation order (the same
    ones every epoch), one column each, panels of at least 128 px, the whole legend."""
    from types import SimpleNamespace

    from spade.training.base import PathPlanningModule
    from spade.training.visualize import MIN_PANEL_PX

    module = SimpleNamespace(grid_size=8)
    for start in (0, 6):  # two validation batches of 6 instances, 2 instances per scenario
        b = _batch(6, 64, seed=start)
        b["scenario_id"] = [f"site/L{(start + i) // 2:03d}" for i in range(6)]
        PathPlanningModule._pick_for_picture(module, b, b["path"] * 0.9)
    picks = module._picture_picks
    assert [p[0] for p in picks] == [f"site/L{k:03d}" for k in range(6)]
    stack = [torch.stack([p[k] for p in picks]) for k in (1, 2, 3, 4)]
    picture = prediction_grid(*stack, torch.tensor([p[5] for p in picks]), titles=[p[0] for p in picks])
    height, width = picture.shape[:2]
    assert width >= 6 * MIN_PANEL_PX and height <= MAX_HEIGHT_PX and height < width


def _drawn(fig):
    fig.canvas.draw()
    return fig.canvas.get_renderer()


@pytest.mark.parametrize("n, size, worst", [(8, 32, True), (4, 64, True), (2, 128, False)])
def test_panel_titles_are_whole_inside_the_picture_and_apart(n: int, size: int, worst: bool) -> None:
    """A title wider than its panel once ran into its neighbour's and past the picture's edge, where the saved
    picture cut it: each is now wrapped or set smaller until it fits, every word kept."""
    import matplotlib.pyplot as plt

    from spade.training.visualize import prediction_figure

    b = _batch(n, size)
    names = [f"#{1000 + k} (a_rather_long_site_name-s{k:03d}/L{k:03d})" for k in range(n)]
    prob = b["path"] * 0.9
    prob[0] = 0  # no path: the longest reason
    fig = prediction_figure(b["state"], b["path"], prob, b["waypoints"], b["resolution"], titles=names, worst=worst)
    try:
        renderer = _drawn(fig)
        boxes = [ax.title.get_window_extent(renderer) for ax in fig.axes]
        for ax, box, name in zip(fig.axes, boxes, names):
            assert fig.bbox.x0 - 0.5 <= box.x0 and box.x1 <= fig.bbox.x1 + 0.5, (ax.title.get_text(), box, fig.bbox)
            assert fig.bbox.y0 - 0.5 <= box.y0 and box.y1 <= fig.bbox.y1 + 0.5, (ax.title.get_text(), box, fig.bbox)
            assert box.y0 >= ax.get_window_extent(renderer).y1 - 0.5  # over its own panel, not on it
            assert "".join(ax.title.get_text().split()).startswith("".join(name.split()))  # every character kept
        for i, first in enumerate(boxes):
            for second in boxes[i + 1:]:
                assert not first.overlaps(second), (first, second)
        (legend,) = [leg.get_window_extent(renderer) for leg in fig.legends]
        assert fig.bbox.x0 <= legend.x0 and legend.x1 <= fig.bbox.x1 and legend.y1 <= fig.bbox.y1, legend
        assert not any(box.overlaps(legend) for box in boxes)
    finally:
        plt.close(fig)


def test_every_panel_draws_the_start_and_the_goal_where_the_instance_has_them() -> None:
    import matplotlib.pyplot as plt

    from spade.metrics.extraction import marker_centre
    from spade.training.visualize import legend_handles, prediction_figure

    b = _batch(3, 64, seed=3)
    fig = prediction_figure(b["state"], b["path"], b["path"] * 0.9, b["waypoints"], b["resolution"])
    try:
        legend = {h.get_label(): h.get_marker() for h in legend_handles(False) if hasattr(h, "get_marker")}
        start_marker = next(m for label, m in legend.items() if label.startswith("robot"))
        goal_marker = legend["goal"]
        assert start_marker != goal_marker and "None" not in (start_marker, goal_marker)
        for k, ax in enumerate(fig.axes):
            state = b["state"][k].numpy()
            for channel, marker in ((1, start_marker), (2, goal_marker)):
                centre = marker_centre(state[channel])
                drawn = [line for line in ax.get_lines() if line.get_marker() == marker
                         and np.allclose(line.get_xydata(), centre[None], atol=0.01)]
                assert len(drawn) == 1, (k, channel, [(ln.get_marker(), ln.get_xydata()) for ln in ax.get_lines()])
                x, y = centre
                x0, x1 = sorted(ax.get_xlim())
                y0, y1 = sorted(ax.get_ylim())
                assert x0 <= x <= x1 and y0 <= y <= y1  # inside the panel's view
    finally:
        plt.close(fig)


def test_the_worst_panels_say_why_they_are_worst() -> None:
    import matplotlib.pyplot as plt

    from spade.training.visualize import prediction_figure, worst_reason

    assert worst_reason(float("inf"), "empty", False) == "worst: no path (nothing above p 0.5)"
    assert worst_reason(31.04, None, True, tail_cm=20.0) == "worst: APE 31.0 cm, over 20 cm"
    assert worst_reason(12.0, None, False) == "worst: APE 12.0 cm, path ends before the goal"
    assert worst_reason(12.0, None, True) == "worst: APE 12.0 cm"
    b = _batch(2, 64, seed=5)
    prob = b["path"] * 0.9
    prob[0] = 0  # nothing predicted
    prob[1] = torch.roll(b["path"][1] * 0.9, shifts=4, dims=-1)  # 4 px = 40 cm to the side
    fig = prediction_figure(b["state"], b["path"], prob, b["waypoints"], b["resolution"], titles=["#1", "#2"],
                            worst=True)
    try:
        titles = [" ".join(ax.title.get_text().split()) for ax in fig.axes]
    finally:
        plt.close(fig)
    assert titles[0] == "#1 worst: no path (nothing above p 0.5)", titles
    assert titles[1].startswith("#2 worst: APE ") and ", over 20 cm" in titles[1], titles
