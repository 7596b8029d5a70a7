"""The desk simulator (python -m spade.ros sim) as a newcomer runs it after `make quickstart`: the tutorials'
procedural maps (warehouse:1) load, a missing file or extra is one line with its fix (cyclonedds: the install line,
not a traceback), Foxglove for the node it starts is a plain option, and no default port is shared between the
sketching app, the node's and the simulator's Foxglove servers. The slow test drives the quickstart's kind of student
(a medium student with Gaussian markers, as a checkpoint) on warehouse:1 through the Nav2 action, and a Foxglove
viewer that connects to both servers after the map was published gets the map, plans and the goal."""

from __future__ import annotations

import re
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from spade.utils.errors import ConfigError

REPO = Path(__file__).resolve().parents[1]
CONF = REPO / "conf"


def compose_sim(*overrides: str):  # noqa: ANN201
    from hydra import compose, initialize_config_dir

    from spade.paths import CONF_DIR

    from omegaconf import OmegaConf

    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = compose("ros_sim", overrides=list(overrides))
    OmegaConf.set_struct(cfg, False)
    cfg.pop("paths")  # Hydra's run folder (unset outside a run); the simulator reads none of it
    return cfg


def test_the_tutorials_procedural_maps_load_and_a_missing_map_is_one_line(tmp_path: Path) -> None:
    from spade.maps import OccupancyMap
    from spade.ros.sim import sim_map

    m = sim_map("warehouse:1")
    assert isinstance(m, OccupancyMap) and m.width > 0 and m.height > 0
    with pytest.raises(ConfigError, match=r"^map=.*site_map\.yaml.*warehouse:101"):
        sim_map(str(tmp_path / "site_map.yaml"))
    with pytest.raises(ConfigError, match=r"^map=warehouse:x: .*seed"):
        sim_map("warehouse:x")


@pytest.mark.parametrize("overrides, match", [
    (["map=warehouse:1", "node_foxglove=true"], "node_foxglove=true: the simulator starts no node without model="),
    (["map=warehouse:1", "model_path=s.onnx", "foxglove=true", "node_foxglove=true", "foxglove_port=9000",
      "node_foxglove_port=9000"], "foxglove_port and node_foxglove_port are both 9000"),
    (["map=warehouse:1", "node_foxglove=maybe"], "node_foxglove"),
    (["map=nowhere/site_map.yaml"], "map=nowhere/site_map.yaml"),
    (["map=warehouse:1", "foxglove=true", "foxglove_host=''"], "foxglove_host='' is empty; give the address"),
    (["map=warehouse:1", "foxglove=true", "foxglove_host=' '"], "foxglove_host=' ' is empty; give the address"),
])
def test_bad_simulator_options_are_refused_in_one_line_before_any_work(overrides: list[str], match: str) -> None:
    pytest.importorskip("foxglove")
    from spade.ros.sim import run_sim

    with pytest.raises(ConfigError, match=re.escape(match)):
        run_sim(compose_sim(*overrides))


def test_no_default_port_is_shared_between_the_sketching_app_and_the_foxglove_servers() -> None:
    from spade.ros.launch import NODE_FOXGLOVE_PORT, SIM_FOXGLOVE_PORT

    sketch = yaml.safe_load((CONF / "sketch.yaml").read_text())["port"]
    node = yaml.safe_load((CONF / "ros.yaml").read_text())["foxglove_port"]
    sim = yaml.safe_load((CONF / "ros_sim.yaml").read_text())
    assert node == sim["node_foxglove_port"] == NODE_FOXGLOVE_PORT == 8765  # Foxglove's own default
    assert sim["foxglove_port"] == SIM_FOXGLOVE_PORT
    assert len({sketch, node, sim["foxglove_port"]}) == 3


@pytest.mark.timeout(120)
@pytest.mark.parametrize("command", [["sim", "map=warehouse:1", "model=student.ckpt"], ["model=student.onnx"]])
def test_a_missing_dds_package_is_one_line_with_the_install_command(tmp_path: Path, command: list[str]) -> None:
    """After `make quickstart` (the onnx extra, no cyclonedds) the simulator and the node name the extra."""
    (tmp_path / "student.ckpt").write_bytes(b"")
    (tmp_path / "student.onnx").write_bytes(b"")
    code = ("import sys; sys.modules['cyclonedds'] = None; sys.argv = ['spade-ros', *sys.argv[1:]]; "
            "from spade.ros.__main__ import cli; cli()")
    run = subprocess.run([sys.executable, "-c", code, *command], cwd=tmp_path, capture_output=True, text=True,
                         timeout=110, env={**__import__("os").environ, "PYTHONPATH": str(REPO),
                                           "SPADE_HOME": str(tmp_path / "home"), "HYDRA_FULL_ERROR": "0"})
    assert run.returncode == 2, run.stderr[-3000:]
    lines = [ln for ln in run.stderr.splitlines() if ln.strip()]
    assert "Traceback" not in run.stderr and len(lines) == 1, run.stderr[-3000:]
    assert lines[0].startswith("error: python -m spade.ros") and "needs the cyclonedds package" in lines[0]
    assert 'pip install -e ".[ros]"' in lines[0] and 'pip install "spade[ros]"' in lines[0]


def test_the_ros_extra_installs_what_the_robot_side_imports() -> None:
    import tomllib

    extras = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    names = {re.split(r"[<>=\[ ]", r)[0] for r in extras["ros"]}
    assert {"cyclonedds", "foxglove-sdk"} <= names


def test_the_docs_simulator_examples_run_as_written() -> None:
    """docs/deployment.md's simulator commands name maps a newcomer has (no site_map.yaml) and plain options."""
    import numpy as np

    from spade.ros.sim import _free, sim_map

    page = (REPO / "docs" / "deployment.md").read_text()
    commands = re.findall(r"^spade-ros sim .*$", page, flags=re.M)
    assert commands, "docs/deployment.md shows no simulator command"
    for line in commands:
        args = line.split("#")[0].replace("$STUDENT", "student.ckpt").split()[2:]
        assert "site_map.yaml" not in line and "node_args" not in line, line
        maps = [a.split("=", 1)[1] for a in args if a.startswith("map=")]
        assert maps and all(re.fullmatch(r"(warehouse|office|hall):\d+", m) for m in maps), line
        cfg = compose_sim(*[a.replace("model=", "model_path=", 1) for a in args])
        assert cfg.map == maps[0]
        m = sim_map(cfg.map)
        poses = ([list(cfg.start)] if cfg.start is not None else []) + \
            ([list(g) for g in cfg.goals] if cfg.goals != "random" else [])
        assert all(_free(m, np.array(p[:2])) for p in poses), line  # free cells of that map
    assert any("node_foxglove=true" in line for line in commands)
    student = re.search(r"^STUDENT=\$\((.*)\)", page, flags=re.M)  # the quickstart's checkpoint, as it names it
    assert student and "checkpoints/epoch*.ckpt" in student.group(1)
    callbacks = yaml.safe_load((CONF / "callbacks" / "default.yaml").read_text())["model_checkpoint"]
    assert callbacks["filename"].startswith("epoch") and callbacks["save_top_k"] == 1  # one: the best


# -- the desk test ----------------------------------------------------------------------------------------------------
def quickstart_student(folder: Path) -> Path:
    """An untrained student of the quickstart's kind: medium, Gaussian start and goal markers, 64 px windows at 0.1
    m/px, saved as the checkpoint entry `make quickstart` leaves."""
    import torch

    from spade.maps.frame import RobotFrame
    from spade.models.builders import build_model

    torch.manual_seed(0)
    net = build_model("student", "medium")
    info = {"role": "student", "config": dict(net.config),
            "data": {"image_size": [64, 64], "resolution_m": 0.1, "frame": RobotFrame.for_size(64).to_json(),
                     "marker_encoding": "gaussian"}}
    ckpt = folder / "student.ckpt"
    torch.save({"spade": info, "state_dict": {f"net.{k}": v for k, v in net.state_dict().items()}}, ckpt)
    return ckpt


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def connect(port: int, seconds: float, proc: subprocess.Popen, log: Path):  # noqa: ANN201
    from ros_support import WsClient

    end = time.monotonic() + seconds
    while time.monotonic() < end:
        assert proc.poll() is None, log.read_text(errors="replace")[-4000:]
        try:
            return WsClient(port, "foxglove.websocket.v1")  # the old protocol name: accepted too
        except (ConnectionError, OSError, AssertionError):
            time.sleep(0.5)
    raise AssertionError(f"no Foxglove server on port {port}:\n{log.read_text(errors='replace')[-4000:]}")


@pytest.mark.slow
@pytest.mark.timeout(400)
def test_the_desk_simulator_runs_the_quickstarts_student_on_warehouse_1_and_a_late_viewer_sees_it(
        tmp_path: Path) -> None:
    pytest.importorskip("cyclonedds")
    pytest.importorskip("foxglove")
    from ros_support import advertised, receive, subscribe
    from ros_support import loopback_env, unique_domain, wait_for

    from spade.ros import messages as M

    student = quickstart_student(tmp_path)
    env = loopback_env(tmp_path)
    sim_port, node_port = free_port(), free_port()
    log = tmp_path / "sim.log"
    args = [sys.executable, "-m", "spade.ros", "sim", "map=warehouse:1", f"model={student}",
            f"domain_id={unique_domain() + 4}", "use_action=true", "num_goals=1", "goal_distance_m=[1.0,1.5]",
            "speed_mps=0.5", "goal_timeout_s=90", "max_seconds=240", "foxglove=true", f"foxglove_port={sim_port}",
            "node_foxglove=true", f"node_foxglove_port={node_port}"]
    with open(log, "w") as out:
        proc = subprocess.Popen(args, cwd=tmp_path, env=env, stdout=out, stderr=subprocess.STDOUT)
    try:
        wait_for(log, "sim: map warehouse", 120)  # the map is published: the viewer comes later
        time.sleep(1.0)
        sim_view = connect(sim_port, 30, proc, log)
        sim_channels = advertised(sim_view, seconds=3)
        assert set(sim_channels) == {"/map", "/amcl_pose", "/goal_pose", "/plan", "/tf"}  # what it carries
        sim_got = receive(sim_view, subscribe(sim_view, sim_channels), {"/map", "/goal_pose", "/plan", "/tf"}, 180)
        assert {"/map", "/goal_pose", "/plan"} <= set(sim_got), (sorted(sim_got), log.read_text()[-4000:])
        assert M.OccupancyGrid.deserialize(sim_got["/map"][0]).info.width > 0
        node_view = connect(node_port, 60, proc, log)  # the node has been up a while: a late viewer too
        node_channels = advertised(node_view, {"/map", "/goal_pose", "/plan", "/plan_window"})
        wanted = {"/map", "/goal_pose", "/plan", "/plan_window", "/plan_probability", "/tf"}
        node_got = receive(node_view, subscribe(node_view, node_channels), wanted, 60)
        assert wanted <= set(node_got), (sorted(node_got), log.read_text()[-4000:])
        goal = M.PoseStamped.deserialize(node_got["/goal_pose"][0])  # the action's goal, shown as a goal
        assert goal.header.frame_id == "map"
        assert len(M.Path.deserialize(node_got["/plan"][0]).poses) >= 2
        proc.wait(240)
    finally:
        if proc.poll() is None:
            proc.terminate()
            proc.wait(30)
    out = log.read_text(errors="replace")
    assert "Traceback" not in out, out[-4000:]
    assert proc.returncode == 0 and "sim: 1/1 goals reached" in out, out[-4000:]
