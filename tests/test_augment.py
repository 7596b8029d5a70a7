"""D4 augmentation keeps images and polylines consistent."""

from __future__ import annotations

import torch

from spade.training.augment import NUM_SYMMETRIES, augment_batch, transform_images, transform_points


def _marked(size: int = 9) -> tuple[torch.Tensor, torch.Tensor]:
    pts = torch.tensor([[1.0, 2.0], [6.0, 2.0], [6.0, 7.0], [3.0, 8.0]])
    img = torch.zeros(1, size, size)
    for x, y in pts.long():
        img[0, y, x] = 1.0
    return img, pts


def test_points_follow_pixels_for_every_symmetry() -> None:
    img, pts = _marked()
    seen = set()
    for g in range(NUM_SYMMETRIES):
        timg, tpts = transform_images(img, g), transform_points(pts, g, 9)
        for x, y in tpts.long():
            assert timg[0, y, x] == 1.0, f"symmetry {g}: point ({x}, {y}) not on its pixel"
        assert timg.sum() == img.sum()
        seen.add(timg.numpy().tobytes())
    assert len(seen) == NUM_SYMMETRIES  # the 8 symmetries are distinct on an asymmetric picture


def test_augment_batch_applies_one_symmetry_per_instance_consistently() -> None:
    img, pts = _marked()
    b = 16
    batch = {
        "state": img.expand(b, 3, 9, 9).clone(),
        "path": img.expand(b, 1, 9, 9).clone(),
        "waypoints": pts.expand(b, 4, 2).clone(),
        "shape": ["L"] * b,
    }
    out = augment_batch(batch, torch.Generator().manual_seed(0))
    assert out["shape"] == batch["shape"]
    assert len({out["path"][i].numpy().tobytes() for i in range(b)}) > 1
    for i in range(b):
        assert torch.equal(out["state"][i, 0], out["path"][i, 0])
        for x, y in out["waypoints"][i].long():
            assert out["path"][i, 0, y, x] == 1.0
