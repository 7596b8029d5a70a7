"""Prerequisites resolve a pinned registry version: the first registered version is the @champion,
later registrations do not move it unless promoted, and the run records which version it used."""

from __future__ import annotations

from pathlib import Path

import pytest
from omegaconf import OmegaConf


def _register(uri: str, tmp_path: Path, tag: str, promote: bool = False) -> tuple[int, str]:
    from lightning.pytorch.loggers import MLFlowLogger

    from spade.tracking.registry import register_checkpoint

    ml = MLFlowLogger(experiment_name="pinning", tracking_uri=uri, artifact_location=str(tmp_path / "artifacts"))
    ckpt = tmp_path / tag / "model.ckpt"
    ckpt.parent.mkdir(parents=True)
    ckpt.write_text(tag)
    ml.experiment.log_artifact(ml.run_id, str(ckpt), artifact_path="checkpoints/best")
    version = register_checkpoint(ml, "spade-test-expert", "checkpoints/best", tags={"row": tag}, promote=promote)
    ml.finalize("success")
    return version, ml.run_id


def test_the_champion_stays_pinned_until_promoted(tmp_path: Path) -> None:
    from mlflow import MlflowClient

    from spade.tracking.registry import fetch_registered

    uri = f"sqlite:///{tmp_path}/mlflow.db"
    cache = tmp_path / "cache"
    assert fetch_registered(uri, "spade-test-expert", cache) is None  # nothing registered yet
    v1, run1 = _register(uri, tmp_path, "first")
    v2, run2 = _register(uri, tmp_path, "second")
    assert (v1, v2) == (1, 2)
    found = fetch_registered(uri, "spade-test-expert", cache)
    assert (found.version, found.run_id, found.path.read_text()) == (1, run1, "first")  # not the newest
    assert fetch_registered(uri, "spade-test-expert", cache, "latest").path.read_text() == "second"
    assert fetch_registered(uri, "spade-test-expert", cache, 2).run_id == run2
    with pytest.raises(ValueError, match=r"has no version 7; its versions are \[1, 2\]"):
        fetch_registered(uri, "spade-test-expert", cache, 7)
    with pytest.raises(ValueError, match="has no alias @staging"):
        fetch_registered(uri, "spade-test-expert", cache, "staging")
    v3, _ = _register(uri, tmp_path, "third", promote=True)
    assert fetch_registered(uri, "spade-test-expert", cache).version == v3 == 3
    # A store written before aliases: the newest version is pinned on first use and stays pinned.
    MlflowClient(tracking_uri=uri).delete_registered_model_alias("spade-test-expert", "champion")
    assert fetch_registered(uri, "spade-test-expert", cache).version == 3
    _register(uri, tmp_path, "fourth")
    assert fetch_registered(uri, "spade-test-expert", cache).version == 3


def test_a_resolved_prerequisite_is_recorded_in_the_runs_config(tmp_path: Path) -> None:
    from spade.experiments.prerequisites import fill_prerequisite as _fill
    from spade.tracking.registry import RegisteredCheckpoint

    cfg = OmegaConf.create({"model": {"margin": {"expert_ckpt": None}},
                            "requires": {"expert": {"experiment": "cond_expert_L", "target": "model.margin.expert_ckpt",
                                                    "version": "champion"}}})
    _fill(cfg, "expert", "model.margin.expert_ckpt",
          RegisteredCheckpoint("spade-x", 4, "abc123", tmp_path / "e.ckpt"))
    assert cfg.model.margin.expert_ckpt == str(tmp_path / "e.ckpt")
    assert OmegaConf.to_container(cfg.requires.expert.resolved) == {"name": "spade-x", "version": 4,
                                                                     "run_id": "abc123"}


def test_the_prerequisite_plan_lists_each_missing_model_once_deepest_first(tmp_path: Path) -> None:
    """A fine-tuning row needs a pretrained Cond-DBC student (which needs the conditional expert) and that expert:
    the plan, made before anything trains, puts the expert first, the student second, and the row's own use of
    the expert last without a second training of it."""
    from spade.experiments.run import prerequisite_plan
    from training_helpers import compose_row

    cfg = compose_row("t2_augbc_finetune_conddbc_U", tmp_path, "logger=none")
    plan = prerequisite_plan(cfg)
    assert [(p.key, p.experiment) for _, p in plan] == [("expert", "cond_expert_L"),
                                                        ("pretrained", "t1_medium_conddbc_L"),
                                                        ("expert", "cond_expert_L")]
    assert plan[0][1].name == plan[2][1].name  # one registered model, trained once (train() skips the repeat)
    assert plan[0][0].run_name == "t1_medium_conddbc_L" and plan[1][0] is cfg and plan[2][0] is cfg
    assert not (tmp_path / "out").exists()  # nothing trained or written
