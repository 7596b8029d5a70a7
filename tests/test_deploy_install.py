"""The deploy install: the planner (and the node) plan with an exported ONNX student where torch is not installed,
and importing the planner then imports no torch. The fast tests hide torch and its stack from a subprocess (an import
hook: as if not installed); the slow one builds a fresh venv with ``pip install --no-deps`` of the package next to
the deploy extra's packages, without torch at all."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from factories import HIDDEN, HIDE

REPO = Path(__file__).resolve().parents[1]


PLAN = textwrap.dedent("""
    import json, sys, time
    t0 = time.perf_counter()
    from spade.planner import Planner
    imported = time.perf_counter() - t0
    from spade.maps import generate_map
    planner = Planner(sys.argv[1])
    t0 = time.perf_counter()
    result = planner.plan(generate_map("warehouse", 4), json.loads(sys.argv[2]), json.loads(sys.argv[3]))
    first = time.perf_counter() - t0
    stack = sorted(m for m in sys.modules if m.split(".")[0] in HIDDEN)
    print(json.dumps({"success": result.success, "code": result.code, "waypoints": result.waypoints.tolist(),
                      "backend": type(planner.backend).__name__, "hidden_imported": stack,
                      "import_s": imported, "first_plan_s": first}))
""")


@pytest.fixture(scope="module")
def onnx_student(tmp_path_factory: pytest.TempPathFactory) -> Path:
    pytest.importorskip("onnxruntime")
    from ros_support import student_files

    return student_files(tmp_path_factory.mktemp("deploy"))[1]


def a_query() -> tuple[list[float], list[float]]:
    """A robot pose and a goal 2 m ahead in open space of warehouse:4."""
    from factories import facing, open_segment

    from spade.maps import generate_map

    a, b = open_segment(generate_map("warehouse", 4), 2.0, seed=5)
    return facing(a, b, 0.2).tolist(), b.tolist()


def run_hidden(code: str, *args: str, cwd: Path | None = None, timeout: float = 120) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    return subprocess.run([sys.executable, "-c", HIDE + code, *args], cwd=cwd or REPO, env=env, capture_output=True,
                          text=True, timeout=timeout)


def test_the_planner_plans_with_onnx_without_torch(onnx_student: Path) -> None:
    from spade.planner import Planner

    pose, goal = a_query()
    run = run_hidden(PLAN, str(onnx_student), json.dumps(pose), json.dumps(goal))
    assert run.returncode == 0, run.stderr
    got = json.loads(run.stdout.strip().splitlines()[-1])
    assert got["hidden_imported"] == [], got["hidden_imported"]
    assert got["success"] and got["backend"] == "OnnxRunner"
    # The same plan as the full install's (torch present, spade.models.modelfile's runner).
    from spade.maps import generate_map

    reference = Planner(onnx_student).plan(generate_map("warehouse", 4), pose, goal)
    np.testing.assert_allclose(got["waypoints"], reference.waypoints, atol=1e-6)
    print(f"deploy install (torch hidden): import spade.planner {got['import_s']:.2f} s, first plan "
          f"{1000 * got['first_plan_s']:.0f} ms")


def test_without_torch_a_checkpoint_is_refused_with_the_fix(onnx_student: Path, tmp_path: Path) -> None:
    ckpt = onnx_student.with_suffix(".ckpt")
    code = textwrap.dedent("""
        import sys
        from spade.planner import Planner, PlannerConfigError
        try:
            Planner(sys.argv[1])
        except PlannerConfigError as err:
            print("refused:", err)
        try:
            Planner(sys.argv[2], fallback="shortest")
        except PlannerConfigError as err:
            print("refused:", err)
    """)
    run = run_hidden(code, str(ckpt), str(onnx_student))
    assert run.returncode == 0, run.stderr
    assert "is a PyTorch checkpoint or TorchScript file, which need torch (not installed here)" in run.stdout
    assert "python -m spade.export" in run.stdout
    assert "fallback='shortest' needs torch" in run.stdout


def test_the_node_replays_without_torch(onnx_student: Path, tmp_path: Path) -> None:
    """python -m spade.ros (Hydra, the node's logic, rosbags) imports no torch: a replay of a recording."""
    from ros_support import robot_bag

    bag = robot_bag(tmp_path / "robot.mcap")
    code = textwrap.dedent("""
        import runpy, sys
        sys.argv = ["spade.ros", *sys.argv[1:]]
        try:
            runpy.run_module("spade.ros", run_name="__main__", alter_sys=True)
        finally:
            print("hidden imported:", sorted(m for m in sys.modules if m.split(".")[0] in HIDDEN))
    """)
    home = tmp_path / "home"
    run = subprocess.run([sys.executable, "-c", HIDE + code, f"model={onnx_student}", f"replay={bag}",
                          f"replay_out={tmp_path / 'out.mcap'}"], cwd=tmp_path, capture_output=True, text=True,
                         timeout=120, env={**os.environ, "PYTHONPATH": str(REPO), "SPADE_HOME": str(home)})
    assert run.returncode == 0, run.stdout + run.stderr
    assert "hidden imported: []" in run.stdout
    assert "replay done: {'map': 1, 'pose': 10, 'goal': 2" in run.stdout and (tmp_path / "out.mcap").is_file()


@pytest.mark.slow
@pytest.mark.timeout(900)
def test_a_fresh_venv_without_torch_plans_with_onnx(onnx_student: Path, tmp_path: Path) -> None:
    """``pip install --no-deps`` of the package plus the deploy extra's packages in a new venv: no torch anywhere, the
    planner plans and ``spade-ros`` replays a recording."""
    import tomllib

    extra = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["optional-dependencies"]["deploy"]
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=120)
    py = venv / "bin" / "python"
    deps = subprocess.run([str(py), "-m", "pip", "install", "-q", *extra], capture_output=True, text=True, timeout=600)
    if deps.returncode != 0:
        pytest.skip(f"the deploy extra's packages could not be installed (no package index?): {deps.stderr[-500:]}")
    own = subprocess.run([str(py), "-m", "pip", "install", "-q", "--no-deps", str(REPO)], capture_output=True,
                         text=True, timeout=600)
    assert own.returncode == 0, own.stderr[-2000:]
    no_torch = subprocess.run([str(py), "-c", "import torch"], capture_output=True, text=True, cwd=tmp_path)
    assert no_torch.returncode != 0 and "No module named 'torch'" in no_torch.stderr

    pose, goal = a_query()
    run = subprocess.run([str(py), "-c", f"HIDDEN = {HIDDEN!r}\n" + PLAN, str(onnx_student), json.dumps(pose),
                          json.dumps(goal)], capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert run.returncode == 0, run.stderr
    got = json.loads(run.stdout.strip().splitlines()[-1])
    assert got["success"] and got["hidden_imported"] == [] and got["backend"] == "OnnxRunner"
    print(f"fresh deploy venv: import spade.planner {got['import_s']:.2f} s, first plan "
          f"{1000 * got['first_plan_s']:.0f} ms")

    from ros_support import robot_bag

    bag = robot_bag(tmp_path / "robot.mcap")
    node = subprocess.run([str(venv / "bin" / "spade-ros"), f"model={onnx_student}", f"replay={bag}"],
                          capture_output=True, text=True, cwd=tmp_path, timeout=120,
                          env={**os.environ, "SPADE_HOME": str(tmp_path / "home")})
    assert node.returncode == 0, node.stdout + node.stderr
    assert "replay done: {'map': 1, 'pose': 10, 'goal': 2" in node.stdout
