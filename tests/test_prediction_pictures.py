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
