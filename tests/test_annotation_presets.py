"""Presets: sizes after the paper, held-out maps, and train/test splits that never share a scenario."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from spade.annotate import annotate
from spade.annotation.run import alias_preset
from spade.annotation.sources import expand_map_specs

CONF = Path(__file__).resolve().parents[1] / "conf"


def preset(name: str, *overrides: str) -> dict:
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        cfg = compose("annotate", overrides=[*alias_preset([f"preset={name}"]), *overrides])
    out = OmegaConf.to_container(cfg, resolve=True)
    out.pop("hydra", None)
    return out


def test_presets_have_the_paper_sizes() -> None:
    l, u, t = preset("lshape"), preset("ushape"), preset("test")
    assert (l["shape"], l["num_instances"], len(l["maps"])) == ("L", 10000, 10)
    assert (u["shape"], u["num_instances"], len(u["maps"])) == ("U", 10000, 10)
    assert (t["shape"], t["num_instances"]) == (["L", "U"], 2000)
    for split in ("train", "test"):
        tr = preset("transfer", f"split={split}")
        assert (tr["shape"], tr["num_instances"]) == ("U", 1000)


def test_held_out_maps_never_appear_in_training() -> None:
    train = set(preset("lshape")["maps"]) | set(preset("ushape")["maps"])
    test_maps = set(preset("test")["maps"])
    transfer = set(preset("transfer")["maps"])
    assert test_maps and transfer
    assert not test_maps & train and not transfer & train and not transfer & test_maps
    assert all(m.startswith(("warehouse", "hall")) for m in test_maps | transfer)  # industrial


def test_transfer_splits_use_disjoint_areas_and_ids() -> None:
    train, test = preset("transfer", "split=train"), preset("transfer", "split=test")
    assert train["out_dir"] != test["out_dir"] and train["seed"] != test["seed"]
    assert not set(train["scenario"]["areas"]) & set(test["scenario"]["areas"])
    assert train["scenario"]["first_index"] + train["scenario"]["max_per_map"] <= test["scenario"]["first_index"]


def test_presets_accept_real_maps(maps_dir: Path) -> None:
    cfg = preset("test", f"maps={maps_dir / 'aws-robomaker-small-warehouse-world'}")
    assert len(expand_map_specs(cfg["maps"])) == 2


@pytest.mark.parametrize("name", ["lshape", "ushape", "test", "transfer"])
def test_presets_run_at_small_size(tmp_path: Path, name: str) -> None:
    cfg = preset(name, f"out_dir={tmp_path / name}", "num_instances=30", "workers=1", "progress=false",
                 "window.size_px=64", "window.resolution_m=0.1", "instances.spacing_m=0.2", "preview.enabled=false",
                 f"maps=[{preset(name)['maps'][0]}]", "alternatives.max_draws=8192")  # the test preset's: fewer draws
    assert annotate(cfg)["instances"] == 30


def test_transfer_train_and_test_never_share_a_scenario(tmp_path: Path) -> None:
    ids, goals = {}, {}
    for split in ("train", "test"):
        cfg = preset("transfer", f"split={split}", f"out_dir={tmp_path / split}", "num_instances=120", "workers=1",
                     "progress=false", "window.size_px=64", "window.resolution_m=0.1", "instances.spacing_m=0.2",
                     "preview.enabled=false")
        annotate(cfg)
        manifest = json.loads((tmp_path / split / "manifest.json").read_text())
        ids[split] = set(manifest["labels"]["scenario_id"]["values"])
    assert ids["train"] and ids["test"] and not ids["train"] & ids["test"]
