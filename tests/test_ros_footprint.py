"""The robot footprint travels with the model: the checkpoint entry records the annotation's robot (radius,
inflation), an export carries it (an older checkpoint's export says it is assumed), and the planner shows it and
refuses a robot that differs (or warns, with footprint_mismatch=warn); the node and spade.plan take the options."""

from __future__ import annotations

import json
import warnings
from pathlib import Path
from types import SimpleNamespace as NS

import pytest
import torch

from spade.deploy.footprint import check_footprint, describe_footprint
from spade.deploy.plan_result import PlannerConfigError
from spade.deploy.student_planner import Planner
from spade.models.modelfile import DEFAULT_FOOTPRINT, checkpoint_entry, export_metadata


def student_ckpt(folder: Path, footprint: dict | None) -> Path:
    from spade.maps.frame import RobotFrame
    from spade.models.builders import build_model

    torch.manual_seed(0)
    net = build_model("student", "small")
    data = {"image_size": [64, 64], "resolution_m": 0.1, "frame": RobotFrame.for_size(64).to_json()}
    if footprint is not None:
        data["footprint"] = footprint
    ckpt = folder / "student.ckpt"
    torch.save({"spade": {"role": "student", "config": dict(net.config), "data": data},
                "state_dict": {f"net.{k}": v for k, v in net.state_dict().items()}}, ckpt)
    return ckpt


def test_the_checkpoint_entry_records_the_annotations_robot() -> None:
    from spade.maps.frame import RobotFrame
    from spade.models.builders import build_model

    net = build_model("student", "small")
    dm = NS(image_size=(64, 64), resolution=0.1, encoding="binary", frame=RobotFrame.for_size(64).to_json(),
            annotation_settings={"robot": {"radius_m": 0.3, "inflation_radius_m": 0.8},
                                 "instances": {"disc_radius_m": 0.1}, "window": {"margin_m": 0.3}})
    data = checkpoint_entry("student", net, dm)["data"]
    assert data["footprint"] == {"radius_m": 0.3, "inflation_radius_m": 0.8}
    meta = export_metadata({"role": "student", "config": dict(net.config), "data": data}, "onnx", source="x.ckpt",
                           opset=17, in_channels=3)
    assert meta["data"]["footprint"] == {"radius_m": 0.3, "inflation_radius_m": 0.8}
    del data["footprint"]  # a checkpoint from before footprints were recorded
    meta = export_metadata({"role": "student", "config": dict(net.config), "data": data}, "onnx", source="x.ckpt",
                           opset=17, in_channels=3)
    assert meta["data"]["footprint"] == {**DEFAULT_FOOTPRINT, "assumed": True}
    json.dumps(meta)  # the ONNX metadata entry is JSON


def test_the_planner_shows_the_footprint_and_refuses_another_robot(tmp_path: Path) -> None:
    ckpt = student_ckpt(tmp_path, {"radius_m": 0.105, "inflation_radius_m": 0.55})
    planner = Planner(ckpt)
    assert planner.footprint == {"radius_m": 0.105, "inflation_radius_m": 0.55}
    assert "trained for a robot radius 0.105 m + inflation 0.55 m" in repr(planner)
    assert Planner(ckpt, robot_radius_m=0.105, inflation_radius_m=0.55).footprint is not None  # the same robot
    with pytest.raises(PlannerConfigError, match=r"robot_radius_m 0.3 m \(the model's 0.105 m\).*footprint_mismatch=warn"):
        Planner(ckpt, robot_radius_m=0.3)
    with pytest.warns(UserWarning, match=r"inflation_radius_m 1 m \(the model's 0.55 m\)"):
        Planner(ckpt, inflation_radius_m=1.0, footprint_mismatch="warn")
    with pytest.raises(PlannerConfigError, match="footprint_mismatch must be 'refuse' or 'warn'"):
        Planner(ckpt, footprint_mismatch="maybe")
    with pytest.raises(PlannerConfigError, match="robot_radius_m=-1"):
        Planner(ckpt, robot_radius_m=-1)


def test_a_model_without_a_footprint_says_so() -> None:
    assert describe_footprint(None) == "robot footprint not recorded"
    assert "assumed" in describe_footprint({**DEFAULT_FOOTPRINT, "assumed": True})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert check_footprint(None, None, None, "refuse", "m.onnx") is None
    with pytest.warns(UserWarning, match="records no robot footprint"):
        assert check_footprint(None, 0.2, None, "refuse", "m.onnx") is None
    with pytest.warns(UserWarning, match="only a warning"):  # an assumed footprint cannot refuse a robot
        assert check_footprint({**DEFAULT_FOOTPRINT, "assumed": True}, 0.3, None, "refuse", "m.onnx")["assumed"]


def test_the_node_and_spade_plan_take_the_footprint_options() -> None:
    from hydra import compose, initialize_config_dir

    from spade.paths import CONF_DIR

    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        for name in ("ros", "plan"):
            overrides = ["planner.robot_radius_m=0.2", "planner.footprint_mismatch=warn"]
            if name == "plan":
                overrides += ["map=m.yaml", "start=[0,0,0]", "goal=[1,1]"]
            cfg = compose(name, overrides=overrides)
            assert cfg.planner.robot_radius_m == 0.2 and cfg.planner.footprint_mismatch == "warn"
            assert cfg.planner.inflation_radius_m is None
