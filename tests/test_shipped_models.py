"""The models SPADE ships (spade/models/shipped.py): pinned, loadable as the module they were trained in, refused
with the fix named when missing or changed, and made from a checkpoint by the ship command."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import torch

from spade.models.modelfile import ModelFileError, load_checkpoint, load_lightning, read_info
from spade.models.shipped import SHIPPED, ship_checkpoint, shipped_path
from spade.utils.hashing import file_sha256


def test_the_quickstart_expert_is_the_pinned_scale_cpu_conditional_expert() -> None:
    from spade.training.expert_module import ExpertModule

    path = shipped_path("cond_expert_L")
    assert file_sha256(path) == SHIPPED["cond_expert_L"].sha256
    info = read_info(path)
    assert info["role"] == "expert" and info["config"]["role"] == "cond_expert"
    assert info["data"]["image_size"] == [64, 64] and info["data"]["resolution_m"] == pytest.approx(0.1)
    assert info["data"]["frame"]["kind"] == "robot"
    # the file was shipped when the row was called expert_cond_L, a name that still composes the same row
    assert any(f"+experiment={name} scale=cpu seed=42" in info["shipped"]["rebuild"]
               for name in ("cond_expert_L", "expert_cond_L"))
    expert = load_lightning(ExpertModule, path)
    assert expert.conditional and expert.hparams["prediction_type"] == "sample"
    assert "optimizer_states" not in load_checkpoint(path)  # weights, not a resumable fit


def test_the_teacher_is_pinned_and_judges_only_gaussian_markers() -> None:
    """The teacher the quickstart's student learns from (docs/results/teacher.md): trained on Gaussian start and goal markers, it
    says so, and refuses a student whose data draw binary discs."""
    from spade.training.expert_mismatch import ExpertMismatchError
    from spade.training.expert_module import ExpertModule

    path = shipped_path("cond_expert_L_gaussian")
    assert file_sha256(path) == SHIPPED["cond_expert_L_gaussian"].sha256
    info = read_info(path)
    assert info["role"] == "expert" and info["data"]["marker_encoding"] == "gaussian"
    assert "+experiment=teacher_L seed=42" in info["shipped"]["rebuild"]
    expert = load_lightning(ExpertModule, path)
    assert expert.marker_encoding == "gaussian" and expert.hparams["prediction_type"] == "sample"
    expert.check_compatible(in_channels=3, image_size=(64, 64), source="teacher", encoding="gaussian")
    with pytest.raises(ExpertMismatchError, match="data.encoding=gaussian"):
        expert.check_compatible(in_channels=3, image_size=(64, 64), source="teacher", encoding="binary")


def test_the_shipped_expert_prefers_demonstrated_paths_to_straight_lines(tmp_path: Path) -> None:
    """What makes it a teacher: on fresh robot-frame L demonstrations (64 px, 0.1 m/px, maps the expert never saw
    in this order) its margin says the straight start-to-goal segment is less expert-like than the demonstration
    on most instances, and the demonstration itself has no margin at all."""
    import numpy as np

    from spade.annotation.run import annotate
    from spade.data.augment import widen_path
    from spade.data.path_dataset import PathDataset
    from spade.metrics.baselines import draw_polylines
    from spade.training.expert_module import ExpertModule
    from spade.training.margin import DiffusionMargin, MarginConfig
    from spade.utils.config import compose_config

    cfg = compose_config("annotate", ["annotate/preset@_global_=lshape", "window.size_px=64", "window.resolution_m=0.1",
                                      "instances.spacing_m=0.1", "num_instances=24", "seed=77",
                                      f"out_dir={tmp_path / 'L'}", "workers=1", "progress=false"])
    annotate(cfg)
    dataset = PathDataset(tmp_path / "L")
    items = [dataset[i] for i in range(len(dataset))]
    state = torch.stack([torch.as_tensor(it["state"]) for it in items])
    demo = widen_path(torch.stack([torch.as_tensor(it["path"]) for it in items]), 3)
    straight = widen_path(draw_polylines([np.asarray(it["waypoints"])[[0, -1]] for it in items], 64, 64), 3)
    expert = load_lightning(ExpertModule, shipped_path("cond_expert_L"))
    margin = DiffusionMargin.from_expert(expert, MarginConfig(expert="conditional", num_noise=8))
    generator = torch.Generator().manual_seed(0)
    with torch.no_grad():
        loss_demo, active_demo = margin(demo, demo, state, generator=generator)
        loss_straight, active_straight = margin(straight, demo, state, generator=generator)
    assert float(loss_demo) == 0.0 and float(active_demo) == 0.0
    assert float(loss_straight) > 0.0 and float(active_straight) > 0.75, (float(loss_straight), float(active_straight))


def test_a_missing_or_changed_shipped_file_is_refused_with_the_fix(tmp_path: Path,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    import spade.models.shipped as shipped

    source = shipped_path("cond_expert_L")
    monkeypatch.setattr(shipped, "WEIGHTS_DIR", tmp_path)
    with pytest.raises(FileNotFoundError, match="is missing: restore it from the repository .* or rebuild it"):
        shipped_path("cond_expert_L")
    target = tmp_path / SHIPPED["cond_expert_L"].file
    shutil.copy(source, target)
    assert shipped_path("cond_expert_L") == str(target)
    with open(target, "r+b") as f:  # one byte changed
        f.seek(-20, 2)
        byte = f.read(1)
        f.seek(-20, 2)
        f.write(bytes([byte[0] ^ 1]))
    with pytest.raises(ModelFileError, match="not its pin .* Restore it from the repository, or rebuild it"):
        shipped_path("cond_expert_L")
    with pytest.raises(KeyError, match="the shipped ones are"):
        shipped_path("uncond_expert_U")


def test_a_config_naming_a_changed_shipped_file_stops_before_the_run(tmp_path: Path,
                                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    import spade.models.shipped as shipped
    from spade.config.checkpoint_checks import check_checkpoint
    from spade.utils.errors import ConfigError

    target = tmp_path / SHIPPED["cond_expert_L"].file
    shutil.copy(shipped_path("cond_expert_L"), target)
    monkeypatch.setattr(shipped, "WEIGHTS_DIR", tmp_path)
    assert check_checkpoint("model.margin.expert_ckpt", target, "expert", "fix")["role"] == "expert"
    data = bytearray(target.read_bytes())
    data[-30] ^= 1  # one bit of the file changed
    target.write_bytes(bytes(data))
    with pytest.raises(ConfigError, match=r"^model.margin.expert_ckpt=.*hashes to .* not its pin"):
        check_checkpoint("model.margin.expert_ckpt", target, "expert", "fix")


def test_ship_command_keeps_the_weights_and_drops_the_resume_state(tiny_checkpoints: dict, tmp_path: Path) -> None:
    from spade.training.expert_module import ExpertModule

    out = tmp_path / "shipped.ckpt"
    summary = ship_checkpoint(tiny_checkpoints["cond"], out, rebuild="python -m spade.train ...", role="expert")
    assert summary["sha256"] == file_sha256(out) and summary["bytes"] == out.stat().st_size
    source, kept = load_checkpoint(tiny_checkpoints["cond"]), load_checkpoint(out)
    assert "optimizer_states" in source and "optimizer_states" not in kept and "loops" not in kept
    assert kept["spade"]["shipped"]["rebuild"] == "python -m spade.train ..."
    original, loaded = load_lightning(ExpertModule, tiny_checkpoints["cond"]), load_lightning(ExpertModule, out)
    for (name, a), (_, b) in zip(original.state_dict().items(), loaded.state_dict().items()):
        assert torch.equal(a, b), name
    with pytest.raises(ModelFileError, match="is not a SPADE expert checkpoint .* role 'student'"):
        ship_checkpoint(tiny_checkpoints["student"], tmp_path / "x.ckpt", rebuild="", role="expert")
    assert not (tmp_path / "x.ckpt").exists()
