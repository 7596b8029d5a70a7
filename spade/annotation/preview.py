"""Contact sheet of instances: the four channels as one colour overlay per instance, in SPADE's palette
(:mod:`spade.utils.palette`: the demonstration green, the robot blue, the goal red)."""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
from PIL import Image

from spade.utils import palette

OCCUPANCY_GREY = np.array([0, 128, 255], dtype=np.uint8)  # unknown black, free grey, obstacle white (Nav2/RViz)
PATH_RGB = palette.rgb(palette.DEMONSTRATION)
START_RGB = palette.rgb(palette.ROBOT)
GOAL_RGB = palette.rgb(palette.GOAL)


def overlay(occupancy: np.ndarray, start: np.ndarray, goal: np.ndarray, path: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 image: occupancy in grey levels, demonstration green, start (the robot) blue, goal red
    (drawn in that order)."""
    grey = OCCUPANCY_GREY[np.asarray(occupancy, dtype=np.uint8)]
    rgb = np.repeat(grey[..., None], 3, axis=2)
    for mask, colour in ((path, PATH_RGB), (start, START_RGB), (goal, GOAL_RGB)):
        rgb[np.asarray(mask, dtype=bool)] = colour
    return rgb


def contact_sheet(images: Sequence[np.ndarray], columns: int = 4, scale: int = 2, gap: int = 4) -> Image.Image:
    """Tile (H, W, 3) images on a dark background, each upscaled ``scale`` times (nearest neighbour)."""
    if not images:
        raise ValueError("contact_sheet needs at least one image")
    h, w = images[0].shape[:2]
    columns = max(1, min(columns, len(images)))
    rows = (len(images) + columns - 1) // columns
    sheet = np.full((rows * (h * scale + gap) + gap, columns * (w * scale + gap) + gap, 3), 40, dtype=np.uint8)
    for i, img in enumerate(images):
        r, c = divmod(i, columns)
        big = np.kron(img, np.ones((scale, scale, 1), dtype=np.uint8))
        y, x = gap + r * (h * scale + gap), gap + c * (w * scale + gap)
        sheet[y:y + h * scale, x:x + w * scale] = big
    return Image.fromarray(sheet)


def write_preview(root: str | Path, count: int, seed: int, scale: int = 2, filename: str = "preview.png") -> Path:
    """Contact sheet of ``count`` random instances of the dataset at ``root``, saved as ``root/filename``."""
    from spade.data.path_dataset import PathDataset  # torch-backed reader; imported here so the tool's core stays light

    ds = PathDataset(root, verify=False)
    n = len(ds)
    pick = np.sort(np.random.default_rng(seed).choice(n, size=min(count, n), replace=False)) if n else []
    images = []
    for i in pick:
        item = ds[int(i)]
        state = np.asarray(item["state"])
        occupancy = np.rint(state[0] * 2).astype(np.uint8)
        images.append(overlay(occupancy, state[1] > 0.5, state[2] > 0.5, np.asarray(item["path"])[0] > 0.5))
    out = Path(root) / filename
    if images:
        contact_sheet(images, columns=int(np.ceil(np.sqrt(len(images)))), scale=scale).save(out)
    return out
