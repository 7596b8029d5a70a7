"""The start and goal marker encodings: binary discs (the paper's) and the sub-pixel ones, in the dataset, the
metrics' floor and the planner."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from spade.data.encoding import MARKER_ENCODINGS, marker_channel, marker_channels
from spade.data.rasterize import render
from spade.metrics.extraction import marker_centre as goal_as_seen  # the weighted centroid

SIZE = 64


def test_binary_is_the_annotation_tools_disc_pixel_for_pixel() -> None:
    rng = np.random.default_rng(0)
    for _ in range(20):
        start, goal = rng.uniform(8, 56, 2), rng.uniform(8, 56, 2)
        inst = render(np.ones((SIZE, SIZE), np.uint8), np.stack([start, goal]), 1.0, 2)
        channels = marker_channels(start, goal, SIZE, 1.0, "binary")
        np.testing.assert_array_equal(channels[0], inst.start)
        np.testing.assert_array_equal(channels[1], inst.goal)


@pytest.mark.parametrize("encoding", ["aa_disc", "gaussian"])
def test_sub_pixel_markers_show_the_exact_position(encoding: str) -> None:
    rng = np.random.default_rng(1)
    for _ in range(20):
        centre = rng.uniform(10, 54, 2)
        channel = marker_channel(centre, SIZE, 1.0, encoding)
        assert channel.max() <= 1.0 and channel.min() >= 0.0
        np.testing.assert_allclose(goal_as_seen(channel), centre, atol=0.02)
    # a third of a pixel moves the channel (the binary disc stays where it is inside its pixel)
    a = np.array([30.1, 30.1])
    b = a + 0.3
    assert not np.allclose(marker_channel(a, SIZE, 1.0, encoding), marker_channel(b, SIZE, 1.0, encoding))
    assert np.array_equal(marker_channel(a, SIZE, 1.0, "binary"), marker_channel(b, SIZE, 1.0, "binary"))
    # the binary disc's centre is the rounded pixel, up to half a pixel off
    assert np.linalg.norm(goal_as_seen(marker_channel(b, SIZE, 1.0, "binary")) - b) > 0.35


def test_unknown_encoding_is_refused_with_the_choices() -> None:
    from spade.data.datamodule import PathDataModule

    with pytest.raises(ValueError, match="aa_disc"):
        marker_channel(np.zeros(2), SIZE, 1.0, "blur")
    with pytest.raises(ValueError, match="binary"):
        PathDataModule("unused", encoding="sharp")


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from spade.annotate import annotate

    from annotation_support import small_cfg

    root = tmp_path_factory.mktemp("encoding") / "set"
    cfg = small_cfg(root, num_instances=12, shape="L")
    cfg["alternatives"].update(count=3, max_draws=12288)
    annotate(cfg)
    return root


def test_the_dataset_redraws_its_markers_at_the_polylines_ends(dataset: Path) -> None:
    from spade.data.path_dataset import PathDataset

    binary, aa = PathDataset(dataset), PathDataset(dataset, encoding="aa_disc")
    for i in range(len(binary)):
        b, a = binary[i], aa[i]
        assert torch.equal(b["state"][0], a["state"][0]) and torch.equal(b["path"], a["path"])
        goal = b["waypoints"][-1].numpy()
        np.testing.assert_allclose(goal_as_seen(a["state"][2].numpy()), goal, atol=0.05)
        np.testing.assert_allclose(goal_as_seen(a["state"][1].numpy()), b["waypoints"][0].numpy(), atol=0.05)
        assert np.linalg.norm(goal_as_seen(b["state"][2].numpy()) - np.round(goal)) < 1e-6


def test_the_floor_loses_the_rounding_under_a_sub_pixel_encoding(dataset: Path) -> None:
    """The floor's path ends on the goal as the input shows it: binary discs leave the rounding in the floor."""
    from torch.utils.data import DataLoader

    from spade.data.path_dataset import PathDataset
    from spade.metrics.preference import PreferenceMetrics

    floors = {}
    for encoding in MARKER_ENCODINGS:
        m = PreferenceMetrics()
        for batch in DataLoader(PathDataset(dataset, encoding=encoding), batch_size=4):
            m.update([w.numpy() for w in batch["waypoints"]], batch["state"], batch["waypoints"],
                     batch["alternatives"], batch["resolution"])
        floors[encoding] = float(m.compute()["floor_cm"])
    assert floors["aa_disc"] < floors["binary"] and floors["gaussian"] < floors["binary"]


def test_the_planner_draws_the_markers_its_model_was_trained_on(tmp_path: Path) -> None:
    from factories import FRAME, RES, ROBOT_DATA, fresh_checkpoint

    from spade.deploy.plan_result import PlannerConfigError
    from spade.deploy.student_planner import Planner

    goal = np.array([40.3, 20.6])
    robot = np.asarray(FRAME.robot_px)
    occupancy = np.ones((SIZE, SIZE), np.uint8)
    for encoding in MARKER_ENCODINGS:
        ckpt = fresh_checkpoint(tmp_path / f"{encoding}.ckpt", {**ROBOT_DATA, "marker_encoding": encoding})
        state = Planner(ckpt).encode(occupancy, robot, goal)
        np.testing.assert_array_equal(state[1:], marker_channels(robot, goal, SIZE, 0.1 / RES, encoding))
    old = fresh_checkpoint(tmp_path / "old.ckpt", ROBOT_DATA)  # a model file from before the encodings: binary
    assert Planner(old).marker_encoding == "binary"
    bad = fresh_checkpoint(tmp_path / "bad.ckpt", {**ROBOT_DATA, "marker_encoding": "blur"})
    with pytest.raises(PlannerConfigError, match="marker_encoding"):
        Planner(bad)


def test_an_expert_judges_only_students_whose_markers_it_was_trained_on(tmp_path: Path) -> None:
    """A guided row may use any marker encoding, as long as its expert was trained on the same one: the expert
    records its data's encoding, an expert saved before it did was trained on binary discs."""
    from spade.config.preflight import validate_train_config
    from spade.training.expert_mismatch import ExpertMismatchError
    from spade.training.expert_module import ExpertModule
    from spade.utils.config import compose_config

    cfg = compose_config("train", ["+experiment=t1_medium_conddbc_L", f"paths.root_dir={tmp_path}",
                                   "data.encoding=aa_disc", "scale=tiny"])
    validate_train_config(cfg)  # the config alone cannot know the expert's encoding: the student checks on load
    old = ExpertModule(conditional=True, preset="tiny")
    assert old.marker_encoding == "binary"
    old.check_compatible(in_channels=3, image_size=None, source="old", encoding="binary")
    with pytest.raises(ExpertMismatchError, match="'binary' markers.*'gaussian'.*data.encoding=binary"):
        old.check_compatible(in_channels=3, image_size=None, source="old", encoding="gaussian")
    new = ExpertModule(conditional=True, preset="tiny", marker_encoding="gaussian")
    new.check_compatible(in_channels=3, image_size=None, source="new", encoding="gaussian")
    with pytest.raises(ExpertMismatchError, match="'gaussian' markers"):
        new.check_compatible(in_channels=3, image_size=None, source="new", encoding="aa_disc")


def test_a_small_blob_between_pixels_still_has_a_centre() -> None:
    """A Gaussian goal of a 0.5 px disc at a pixel corner has no pixel above 0.5: the metrics' extraction, the
    decoder and the floor read its weighted centroid (the run that found it failed on its real-map test)."""
    from spade.metrics.extraction import marker_centre

    centre = np.array([30.5, 30.5])
    channel = marker_channel(centre, SIZE, 0.5, "gaussian")
    assert channel.max() < 0.5
    np.testing.assert_allclose(marker_centre(channel), centre, atol=1e-6)
    with pytest.raises(ValueError, match="empty"):
        marker_centre(np.zeros((SIZE, SIZE)))
