"""The robot-frame augmentation (left-right mirror about the robot) and the widened path target."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from spade.data.augment import augment_batch, check_augmentation, mirror_images, mirror_points, widen_path
from spade.data.rasterize import robot_instance
from spade.maps.frame import RobotFrame


def _instance(turn: float):
    """A robot-frame instance of an L turning left (turn=-1) or right (turn=+1) in map pixels."""
    t = np.linspace(0, 1, 80)
    leg = np.stack([np.full(40, 50.0), np.linspace(60, 40, 40)], axis=1)  # heading north (up the map image)
    arc = np.stack([50 + turn * (10 - 10 * np.cos(t * np.pi / 2)), 40 - 10 * np.sin(t * np.pi / 2)], axis=1)
    pts = np.concatenate([leg, arc])
    grid = np.ones((120, 120), np.uint8)
    grid[:, 75:78] = 2
    return robot_instance(grid, pts, RobotFrame.for_size(64), 2, 1.5, 32)


def test_mirror_about_the_robot_turns_a_left_turn_into_the_right_one() -> None:
    left, right = _instance(-1.0), _instance(+1.0)
    rx = RobotFrame.for_size(64).robot_px[0]
    mirrored = mirror_images(torch.from_numpy(left.path.astype(np.float32)), rx).numpy() > 0.5
    assert (mirrored == right.path).mean() > 0.995  # same curve up to a pixel or two of rounding
    start = mirror_images(torch.from_numpy(left.start.astype(np.float32)), rx).numpy() > 0.5
    assert np.array_equal(start, left.start)  # the robot stays on its pixel
    wp = mirror_points(torch.from_numpy(left.waypoints), rx).numpy()
    np.testing.assert_allclose(wp, right.waypoints, atol=0.05)
    img = torch.arange(64.0).repeat(2, 64, 1)
    out = mirror_images(img, rx)
    assert out[0, 5, 32] == 32 and out[0, 5, 40] == 24 and out[0, 5, 0] == 0  # column 0 comes from outside


def test_augment_batch_mirrors_about_half_and_keeps_pairs_consistent() -> None:
    inst = _instance(-1.0)
    state = torch.from_numpy(np.stack([inst.occupancy * 0.5, inst.start, inst.goal]).astype(np.float32))
    batch = {"state": state.repeat(64, 1, 1, 1), "path": torch.from_numpy(inst.path[None].astype(np.float32)).repeat(64, 1, 1, 1),
             "waypoints": torch.from_numpy(inst.waypoints).repeat(64, 1, 1)}
    batch["target"] = widen_path(batch["path"], 3)
    out = augment_batch(batch, 32.0, torch.Generator().manual_seed(0))
    flipped = (out["waypoints"][:, -1, 0] != batch["waypoints"][:, -1, 0])
    assert 16 < int(flipped.sum()) < 48
    for i in range(64):  # the goal disc is where the waypoints end, in both halves
        gx, gy = out["waypoints"][i, -1].round().long()
        assert out["state"][i, 2, gy, gx] == 1 and out["path"][i, 0].sum() == batch["path"][0, 0].sum()
        assert (out["target"][i, 0] >= out["path"][i, 0]).all()


def test_widen_path_and_bad_settings() -> None:
    path = torch.zeros(1, 1, 9, 9)
    path[0, 0, 4, :] = 1
    assert widen_path(path, 1) is path
    wide = widen_path(path, 3)
    assert wide[0, 0, 3:6].sum() == 27 and wide.sum() == 27
    with pytest.raises(ValueError, match="odd"):
        widen_path(path, 2)
    with pytest.raises(ValueError, match="mirror"):
        check_augmentation("d4")
    assert check_augmentation(False) == "none" and check_augmentation("mirror") == "mirror"
