"""Every experiment composes and instantiates; every Table 1-3 row runs one batch of each stage at tiny scale."""

from __future__ import annotations

from pathlib import Path

import hydra
import pytest
import torch

from spade.paths import CONF_DIR
from spade.experiments.run import train
from training_helpers import compose_row

TABLES = {"table1": 22, "ablation_finetune": 3, "ablation_scratch": 2}
ROWS = sorted(p.stem for p in (CONF_DIR / "experiment").glob("*.yaml") if p.stem.startswith(("t1_", "t2_", "t3_", "expert_")))


def test_there_is_one_experiment_per_row() -> None:
    assert len(ROWS) == 27  # 18 students + 4 experts + 3 (Table 2) + 2 (Table 3)


@pytest.mark.parametrize("table,count", sorted(TABLES.items()))
def test_table_compositions_launch_their_rows(table: str, count: int, spade_home: Path) -> None:
    cfg = compose_row(table, spade_home, hydra_config=True)
    rows = cfg.hydra.sweeper.params.experiment.split(",")
    assert cfg.hydra.mode.name == "MULTIRUN" and len(rows) == count
    assert all(r in ROWS for r in rows)


def _fill_requirements(cfg, ckpts: dict[str, str]) -> list[str]:
    out = []
    for req in (cfg.get("requires") or {}).values():
        if req.target == "model.init_ckpt":
            out.append(f"model.init_ckpt={ckpts['student']}")
        else:
            key = "uncond" if "uncond" in req.experiment else "cond"
            out.append(f"model.guidance.expert_ckpt={ckpts[key]}")
    return out


@pytest.mark.parametrize("row", ROWS)
def test_row_composes_instantiates_and_runs_fast_dev_run(row: str, spade_home: Path, tiny_checkpoints: dict) -> None:
    cfg = compose_row(row, spade_home)
    cfg = compose_row(row, spade_home, "debug=fdr", "logger=none", *_fill_requirements(cfg, tiny_checkpoints))
    assert cfg.tags.table in ("table1", "table2", "table3")
    metrics, objects = train(cfg)
    assert "test/ape_cm" in metrics and "test/hd19" in metrics
    model = objects["model"]
    if cfg.model.get("guidance"):
        assert model.margin is not None
        assert all(not p.requires_grad for p in model.margin.expert.parameters())


def test_scale_presets_compose(spade_home: Path) -> None:
    for scale in ("tiny", "cpu", "paper"):
        cfg = compose_row("t1_medium_conddbc_L", spade_home, f"scale={scale}")
        dm = hydra.utils.instantiate(cfg.data)
        assert dm.batch_size == cfg.scale.batch_size
    cfg = compose_row("expert_uncond_U", spade_home, "scale=paper")
    with torch.device("meta"):
        model = hydra.utils.instantiate(cfg.model)
    assert sum(p.numel() for p in model.net.parameters()) > 9e8
