"""spade.models.modelfile: safe loading (a pickle that would run code is refused and nothing runs), the entry a
fit writes, real Lightning checkpoints under weights_only=True, one runner for checkpoint / ONNX / TorchScript,
and the device policy."""

from __future__ import annotations

import functools
import os
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from spade.maps.frame import RobotFrame
from spade.models.builders import build_model
from spade.models.modelfile import (
    INPUT_ENCODING,
    ModelFileError,
    UnsafeModelFileError,
    checkpoint_entry,
    file_format,
    load_checkpoint,
    load_lightning,
    load_network,
    open_model,
    read_info,
    resolve_device,
    robot_frame,
    write_checkpoint_entry,
)

FRAME = RobotFrame.for_size(32).to_json()
DATA = {"image_size": [32, 32], "resolution_m": 0.2, "frame": FRAME}


def _write_marker(path: str) -> str:
    """What a malicious checkpoint would call while being unpickled (here: leaves a file behind)."""
    Path(path).write_text("code ran")
    return "payload"


class Payload:
    """An object whose unpickling calls :func:`_write_marker` (the classic ``__reduce__`` attack)."""

    def __init__(self, marker: Path) -> None:
        self.marker = str(marker)

    def __reduce__(self):
        return (_write_marker, (self.marker,))


def student_checkpoint(path: Path, data: dict | None = DATA, **extra) -> Path:
    torch.manual_seed(0)
    net = build_model("student", "small")
    info = {"role": "student", "config": dict(net.config)}
    if data is not None:
        info["data"] = data
    torch.save({"spade": info, "state_dict": {f"net.{k}": v for k, v in net.state_dict().items()}, **extra}, path)
    return path


# ------------------------------------------------------------------------------------------------ safe loading
def test_a_checkpoint_that_would_run_code_is_refused_and_nothing_runs(tmp_path: Path, spade_home: Path) -> None:
    from spade.evaluate import load_module
    from spade.config.checkpoint_checks import checkpoint_info
    from spade.planner import Planner
    from spade.training.instantiate import run_id_from_checkpoint
    from spade.training.student_module import StudentModule

    marker = tmp_path / "marker.txt"
    evil = student_checkpoint(tmp_path / "evil.ckpt", extra_entry=Payload(marker))
    readers = [
        lambda: load_checkpoint(evil), lambda: read_info(evil), lambda: load_network(evil),
        lambda: open_model(evil), lambda: load_lightning(StudentModule, evil), lambda: load_module(evil),
        lambda: run_id_from_checkpoint(evil), lambda: Planner(evil),
        lambda: StudentModule(size="small", init_ckpt=str(evil)), lambda: checkpoint_info(evil),
    ]
    for read in readers:
        with pytest.raises(UnsafeModelFileError) as info:
            read()
        message = str(info.value)
        assert str(evil) in message and "_write_marker" in message and "weights_only=True" in message
        assert not marker.exists(), "loading ran the checkpoint's code"
    # The test can fail: the same file loaded the unsafe way does run the payload.
    torch.load(evil, weights_only=False)
    assert marker.read_text() == "code ran"


def _boring_trainer(root: Path, steps: int):
    import lightning as L

    return L.Trainer(default_root_dir=root, max_steps=steps, accelerator="cpu", logger=False,
                     enable_checkpointing=False, enable_progress_bar=False, enable_model_summary=False)


def test_lightning_resume_and_test_checkpoints_are_loaded_safely(tmp_path: Path, spade_home: Path) -> None:
    """The checkpoints Lightning opens itself (``ckpt_path`` to resume a fit, the best one to test) go through
    weights_only=True with the allow-list: a pickle that would run code is refused before it runs, a genuine
    checkpoint still resumes."""
    from lightning.pytorch.demos.boring_classes import BoringModel

    from spade.experiments.run import from_checkpoint, train
    from spade.utils.errors import ConfigError
    from training_helpers import compose_row

    marker = tmp_path / "marker.txt"
    evil = student_checkpoint(tmp_path / "evil.ckpt", extra_entry=Payload(marker))
    for step in ("fit", "test"):
        trainer = _boring_trainer(tmp_path, 1)
        with pytest.raises(UnsafeModelFileError) as info:
            from_checkpoint(getattr(trainer, step), evil, model=BoringModel())
        assert str(evil) in str(info.value) and "_write_marker" in str(info.value)
        assert not marker.exists(), f"trainer.{step}(ckpt_path=...) ran the checkpoint's code"
    # The resume path of a run (python -m spade.train ... ckpt_path=PATH) refuses it before anything starts.
    with pytest.raises(ConfigError, match=r"ckpt_path=.*evil\.ckpt was refused as unsafe \(UnsafeModelFileError\)"):
        train(compose_row("t1_small_bc_L", spade_home, f"ckpt_path={evil}"))
    assert not marker.exists()

    # A genuine Lightning checkpoint (loops, optimiser and scheduler states) resumes and tests under the same rule.
    trainer = _boring_trainer(tmp_path, 2)
    trainer.fit(BoringModel())
    genuine = tmp_path / "genuine.ckpt"
    trainer.save_checkpoint(genuine)
    resumed = _boring_trainer(tmp_path, 4)
    from_checkpoint(resumed.fit, genuine, model=BoringModel())
    assert resumed.global_step == 4
    assert from_checkpoint(resumed.test, genuine, model=BoringModel(), verbose=False)


def test_optimiser_factories_and_arbitrary_objects_are_refused(tmp_path: Path) -> None:
    partial = student_checkpoint(tmp_path / "partial.ckpt",
                                 hyper_parameters={"optimizer": functools.partial(torch.optim.AdamW, lr=1e-3)})
    with pytest.raises(UnsafeModelFileError, match="functools.partial"):
        load_checkpoint(partial)
    system = student_checkpoint(tmp_path / "system.ckpt", extra=os.system)
    with pytest.raises(UnsafeModelFileError, match="system"):
        load_checkpoint(system)


def test_omegaconf_hyper_parameters_load_and_are_written_plain(tmp_path: Path) -> None:
    hp = OmegaConf.create({"size": "small", "metrics": {"hd_threshold": 19}, "margin": {"lambda_dm": [0.1, None]}})
    path = student_checkpoint(tmp_path / "omega.ckpt", hyper_parameters=hp, hparams_type=type(hp),
                              some_path=Path("/tmp/somewhere"))
    loaded = load_checkpoint(path)  # allow-listed: OmegaConf containers and pathlib paths only rebuild data
    assert OmegaConf.to_container(loaded["hyper_parameters"]) == OmegaConf.to_container(hp)
    assert loaded["some_path"] == Path("/tmp/somewhere")
    # What a fit writes has no OmegaConf left in it.
    checkpoint = {"hyper_parameters": hp, "hparams_type": type(hp)}
    write_checkpoint_entry(checkpoint, "student", build_model("student", "small"))
    assert checkpoint["hyper_parameters"] == {"size": "small", "metrics": {"hd_threshold": 19},
                                              "margin": {"lambda_dm": [0.1, None]}}
    assert type(checkpoint["hyper_parameters"]["metrics"]) is dict and "hparams_type" not in checkpoint


def test_not_a_checkpoint(tmp_path: Path) -> None:
    junk = tmp_path / "junk.ckpt"
    junk.write_bytes(b"\x80\x02garbage")
    with pytest.raises(ModelFileError, match="junk.ckpt is not a readable PyTorch checkpoint") as info:
        load_checkpoint(junk)
    assert not isinstance(info.value, UnsafeModelFileError)  # damaged, not dangerous
    with pytest.raises(FileNotFoundError, match="spade.train"):
        load_checkpoint(tmp_path / "absent.ckpt")
    torch.save({"state_dict": {}}, tmp_path / "plain.ckpt")
    with pytest.raises(ModelFileError, match="no 'spade' entry"):
        load_network(tmp_path / "plain.ckpt")


# ------------------------------------------------------------------------------------------------ the entry
def test_checkpoint_entry_records_the_windows_and_run() -> None:
    class DataModule:
        image_size, resolution, frame = (64, 64), 0.1, RobotFrame.for_size(64).to_json()

    class MLFlowLogger:
        run_id = "r1"

    net = build_model("student", "small")
    info = checkpoint_entry("student", net, DataModule(), [object(), MLFlowLogger()])
    assert info == {"role": "student", "config": dict(net.config), "mlflow_run_id": "r1",
                    "data": {"image_size": [64, 64], "resolution_m": 0.1, "input_encoding": INPUT_ENCODING,
                             "marker_encoding": "binary", "frame": RobotFrame.for_size(64).to_json()}}
    assert checkpoint_entry("expert", net) == {"role": "expert", "config": dict(net.config)}


def test_real_checkpoints_of_a_tiny_fit_load_safely(tiny_checkpoints: dict[str, str]) -> None:
    """What Lightning writes (loops, callbacks, hyper-parameters, optimiser states) loads with weights_only=True."""
    from spade.evaluate import load_module
    from spade.training.expert_module import ExpertModule
    from spade.training.student_module import StudentModule

    for key, path in tiny_checkpoints.items():
        checkpoint = load_checkpoint(path)
        assert {"state_dict", "hyper_parameters", "loops", "optimizer_states", "spade"} <= set(checkpoint)
        info = checkpoint["spade"]
        assert info["role"] == ("student" if key == "student" else "expert")
        assert info["data"]["input_encoding"] == INPUT_ENCODING and info["data"]["resolution_m"] == pytest.approx(0.1)
        # The annotation settings of the training set (its manifest), for the planner's discs and goal margin.
        assert info["data"]["disc_radius_m"] == pytest.approx(0.1) and info["data"]["margin_m"] == pytest.approx(0.3)
        assert RobotFrame.from_json(robot_frame(info, path)) == RobotFrame.for_size(info["data"]["image_size"][0])
        module = load_module(path)
        assert isinstance(module, StudentModule if key == "student" else ExpertModule)
    expert = load_lightning(ExpertModule, tiny_checkpoints["cond"])
    assert expert.conditional
    net, info = load_network(tiny_checkpoints["student"])
    student = load_lightning(StudentModule, tiny_checkpoints["student"]).eval()
    state = torch.rand(2, 3, 64, 64)
    with torch.no_grad():
        torch.testing.assert_close(net(state), student(state))


def test_robot_frame_is_required_for_deployment(tmp_path: Path) -> None:
    assert robot_frame({"data": DATA}, "x.ckpt") == FRAME
    for data in (None, {"image_size": [32, 32], "resolution_m": 0.2}, {**DATA, "frame": {"kind": "axis"}}):
        with pytest.raises(ModelFileError, match=r"x\.ckpt.*axis-aligned.*[Rr]etrain"):
            robot_frame({"data": data} if data else {}, "x.ckpt")


# ------------------------------------------------------------------------------------------------ running
@pytest.mark.filterwarnings("ignore::DeprecationWarning")
def test_one_runner_for_checkpoint_onnx_and_torchscript(tmp_path: Path) -> None:
    pytest.importorskip("onnxruntime")
    from spade.deploy.export import export_student

    ckpt = student_checkpoint(tmp_path / "s.ckpt")
    exports = {fmt: export_student(ckpt, tmp_path / f"s_{fmt}", fmt, latency_runs=0).out_path
               for fmt in ("onnx", "torchscript")}
    renamed = tmp_path / "model.bin"  # the kind comes from the contents, not the name
    shutil.copy(exports["onnx"], renamed)
    state = np.random.default_rng(0).random((3, 3, 32, 32), dtype=np.float32)
    reference = open_model(ckpt)
    assert (reference.format, reference.runtime, reference.device) == ("checkpoint", "pytorch", "cpu")
    expected = reference(state)
    assert expected.shape == (3, 1, 32, 32) and expected.dtype == np.float32
    for path, fmt in ((exports["onnx"], "onnx"), (exports["torchscript"], "torchscript"), (renamed, "onnx")):
        assert file_format(path) == fmt
        runner = open_model(path)
        assert runner.format == fmt and runner.info["data"]["frame"] == FRAME
        assert runner.info["role"] == "student" and runner.info["config"] == reference.info["config"]
        np.testing.assert_allclose(runner(torch.from_numpy(state)), expected, atol=1e-4)
        np.testing.assert_allclose(runner.logits(state), expected, atol=1e-4)
    torch.save({"spade": {"role": "expert", "config": {}}, "state_dict": {}}, tmp_path / "e.ckpt")
    with pytest.raises(ModelFileError, match="not 'student'"):
        open_model(tmp_path / "e.ckpt")


def test_device_policy() -> None:
    assert resolve_device("cpu") == "cpu" and resolve_device(None) == "cpu"
    assert resolve_device("auto", cuda_available=False) == "cpu"
    assert resolve_device("auto", cuda_available=True) == "cuda"
    assert resolve_device("cuda:1", cuda_available=True) == "cuda:1"
    with pytest.raises(ModelFileError, match="device=cpu"):
        resolve_device("cuda", cuda_available=False)
    with pytest.raises(ModelFileError, match="cpu, cuda, cuda:N or auto"):
        resolve_device("tpu")


def test_no_other_checkpoint_loading_in_spade() -> None:
    """One owner: no module of spade/ but the model-file module calls torch.load or load_from_checkpoint."""
    root = Path(__file__).resolve().parents[1] / "spade"
    owners = {root / "models" / "modelfile.py", root / "metrics" / "features.py"}  # features: FID extractor weights
    found = [str(p.relative_to(root)) for p in root.rglob("*.py") if p not in owners
             and ("torch.load(" in p.read_text() or ".load_from_checkpoint(" in p.read_text())]
    assert found == [], f"checkpoints read outside spade.models.modelfile: {found}"
    # Lightning's own loads (a Trainer method given a ckpt_path) go through spade.experiments.run.from_checkpoint.
    direct = [str(p.relative_to(root)) for p in root.rglob("*.py")
              if re.search(r"\.(fit|validate|test|predict)\([^)]*ckpt_path=", p.read_text())]
    assert direct == [], f"Trainer loads a checkpoint without weights_only=True and the allow-list in: {direct}"
