"""Shared set-up for the annotation tests: a small annotate config, and the checks every generated dataset
passes (sound instances, the executed turn of each shape)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from omegaconf import OmegaConf

from spade.annotation.execution import total_turn_deg
from spade.annotation.invariants import instance_problems
from spade.annotation.templates import SHAPES
from spade.data.path_dataset import PathDataset

ROOT = Path(__file__).resolve().parents[1]


def small_cfg(out_dir: Path, **over) -> dict:
    """64 px x 0.1 m/px windows (the default 6.4 m), a few instances, one worker unless asked."""
    cfg = OmegaConf.to_container(OmegaConf.load(ROOT / "conf" / "annotate.yaml"), resolve=False)
    cfg.pop("defaults", None)
    cfg.pop("hydra", None)
    cfg.update(out_dir=str(out_dir), workers=1, progress=False, num_instances=60, num_waypoints=32,
               maps=["warehouse:1", "office:2"])
    cfg["window"].update(size_px=64, resolution_m=0.1)
    cfg["instances"]["spacing_m"] = 0.15
    cfg["preview"]["count"] = 4
    for key, value in over.items():
        section, _, leaf = key.partition(".")
        if leaf:
            cfg[section][leaf] = value
        else:
            cfg[key] = value
    return cfg


def check_dataset(root: Path, shapes: set[str], tolerance: float) -> dict:
    ds = PathDataset(root)
    manifest = json.loads((root / "manifest.json").read_text())
    first_of: dict[str, int] = {}
    for i in range(len(ds)):
        item = ds[i]
        state = item["state"].numpy()
        occupancy = np.rint(state[0] * 2).astype(np.uint8)
        problems = instance_problems(occupancy, state[1] > 0.5, state[2] > 0.5, item["path"].numpy()[0] > 0.5,
                                     item["waypoints"].numpy())
        assert problems == [], (i, item["scenario_id"], problems)
        first_of.setdefault(item["scenario_id"], i)
        assert item["shape"] in shapes
    for sid, i in first_of.items():  # the first state of a scenario holds its whole executed path
        item = ds[i]
        turn = total_turn_deg(item["waypoints"].numpy().astype(np.float64), 2)
        assert abs(abs(turn) - SHAPES[item["shape"]]) <= tolerance + 10, (sid, turn)
    return manifest
