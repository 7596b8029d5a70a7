"""``python -m spade.perf.hostile_probes OUT.json [--only NAME ...]``: the entry points given bad input as a hostile
but honest user would, each a ``python -m spade.X`` process in a SPADE_HOME of its own, at the tiny scale, its
outcome classified mechanically:

- **clear**: a non-zero exit and one ``error: <what is wrong>; <the fix>`` line naming the probe's key or file,
  no traceback, nothing left behind (a FAILED run, a half-made store);
- **unclear**: a traceback, a message without its fix or without the key, a silent exit 0 on bad input, a run
  still going at its time limit, or a refusal that left something behind;
- **wrong**: a bad input accepted and acted on (a plan made from a forged model, poisoned data verified OK).

A probe whose optional dependency is missing, or that cannot be made on this machine (read-only folders as root),
is skipped and recorded. The record is ``docs/results/records/reliability/probes.json``;
:func:`render_section` writes its counts and its unclear and wrong rows into ``docs/reference/reliability.md``.
"""

from __future__ import annotations

import argparse
import datetime
import importlib.util
import json
import os
import re
import signal
import socket
import sqlite3
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np
from skimage.draw import disk, line

from spade.data import DatasetWriter, resample_polyline
from spade.utils.provenance import REPO_ROOT, commit, machine
from spade.deploy.export import export_student
from spade.deploy.mlflow_models import mlflow_client
from spade.deploy.mlflow_store import ensure_store
from spade.data.format import MANIFEST, MANIFEST_CHECKSUM, manifest_checksum
from spade.maps import OccupancyMap, save_ros_map
from spade.models.modelfile import read_metadata, untrained_student

REPO = Path(__file__).resolve().parents[2]
RECORD = REPO / "docs" / "results" / "records" / "reliability" / "probes.json"
PAGE = REPO / "docs" / "reference" / "reliability.md"
BEGIN, END = "<!-- spade:hostile-probes -->", "<!-- spade:hostile-probes-end -->"
TIMEOUT_S = 120.0
VERDICTS = ("clear", "unclear", "wrong")


# -- the classifier ---------------------------------------------------------------------------------------------------
@dataclass
class Outcome:
    """What one probe's command did: its exit status (None: still running at its time limit), its output, and what
    the probe found in its folder afterwards."""

    rc: int | None
    output: str
    acted: bool = False  # a result made from the bad input (a plan, a verified dataset, a served model)
    left: str = ""  # what a refusal left behind ("a FAILED run", "a store"), empty when nothing
    seconds: float = 0.0
    ok: bool = False  # a probe of a valid input under stress (a race, an interrupt) that came through


def error_lines(output: str) -> list[str]:
    return [ln.strip() for ln in output.splitlines() if ln.strip().startswith("error: ")]


def _scrubbed(text: str, root: Path, work: Path | None = None) -> str:
    """``text`` without the writing machine's paths: the probe's folder as WORK, the run's temporary root as TMP,
    the checkout (and its virtual environment) as ``.``, the home folder as ``~``."""
    for path, shown in ((work, "WORK"), (root, "TMP"), (REPO_ROOT, "."), (Path.home(), "~")):
        if path is not None:
            text = text.replace(str(path), shown)
    return text


def classify(outcome: Outcome, names: str = "", report: bool = False) -> tuple[str, str]:
    """``(verdict, why)`` of one outcome; ``names``: a word the error line must hold (the key or the file);
    ``report``: a verifier's answer, whose problems are ``- <file>: <problem>. <fix>`` lines under its summary
    (each counts as an error line)."""
    if outcome.acted:
        return "wrong", "the bad input was accepted and acted on"
    if outcome.ok:
        return "clear", ""
    if outcome.rc is None:
        return "unclear", "still running at its time limit"
    if outcome.rc == 0:
        return "unclear", "exit 0 on bad input, no error"
    if "Traceback (most recent call last)" in outcome.output:
        return "unclear", "a traceback"
    errors = error_lines(outcome.output)
    if report and not errors:
        errors = [ln.strip()[2:] for ln in outcome.output.splitlines() if ln.strip().startswith("- ")][:1]
        errors = [e.replace(". ", "; ", 1) for e in errors if " the file" in e or "Re-generate" in e]
    if len(errors) != 1:
        return "unclear", f"{len(errors)} error: lines, not one"
    if "; " not in errors[0]:
        return "unclear", "an error without its fix"
    if names and names.lower() not in errors[0].lower():
        return "unclear", f"the error does not name {names!r}"
    if outcome.left:
        return "unclear", f"the refusal left {outcome.left}"
    return "clear", ""


# -- the material the probes point at ---------------------------------------------------------------------------------
def _instance(rng: np.random.Generator, size: int = 32, k: int = 16) -> dict[str, Any]:
    occ = np.ones((size, size), dtype=np.uint8)
    occ[0, :] = 2
    sx, sy = int(rng.integers(4, size // 2)), int(rng.integers(size // 2 + 2, size - 4))
    gx, gy = int(rng.integers(size // 2, size - 4)), int(rng.integers(3, size // 2 - 2))
    corners = np.array([[sx, sy], [sx, gy], [gx, gy]], dtype=np.float64)
    path = np.zeros((size, size), dtype=bool)
    for (x0, y0), (x1, y1) in zip(corners[:-1], corners[1:]):
        rr, cc = line(int(y0), int(x0), int(y1), int(x1))
        path[rr, cc] = True
    start, goal = np.zeros_like(path), np.zeros_like(path)
    start[disk((sy, sx), 2, shape=path.shape)] = True
    goal[disk((gy, gx), 2, shape=path.shape)] = True
    return {"occupancy": occ, "start": start, "goal": goal, "path": path,
            "waypoints": resample_polyline(corners, k).astype(np.float32),
            "pose": (float(sx) * 0.05, float(sy) * 0.05, float(rng.uniform(-np.pi, np.pi)))}


def dataset(root: Path, n: int = 4, waypoint_scale: float = 1.0) -> Path:
    """A 32 px, 0.05 m/px dataset of ``n`` L instances (waypoints multiplied by ``waypoint_scale``)."""
    rng = np.random.default_rng(0)
    with DatasetWriter(root, image_size=32, resolution=0.05, num_waypoints=16, generator_config={"seed": 0}) as w:
        for i in range(n):
            inst = _instance(rng)
            inst["waypoints"] = inst["waypoints"] * np.float32(waypoint_scale)
            w.add(**inst, shape="L", map_id="m0", scenario_id=f"m0/s{i}")
    return root


def poison(root: Path, name: str, value: float) -> Path:
    """Every value of the dataset's array ``name`` set to ``value``, the checksums recomputed (an edit no checksum
    catches)."""
    import hashlib

    manifest = json.loads((root / MANIFEST).read_text())
    spec = manifest["files"][name]
    path = root / spec["file"]
    arr = np.fromfile(path, dtype=np.dtype(spec["dtype"]))
    arr[:] = value
    arr.tofile(path)
    spec["sha256"] = hashlib.sha256(path.read_bytes()).hexdigest()
    manifest[MANIFEST_CHECKSUM] = manifest_checksum(manifest)
    (root / MANIFEST).write_text(json.dumps(manifest, indent=1, sort_keys=True))
    return root


def site_map(root: Path) -> Path:
    """A 12 m x 10 m walled site at 0.1 m/px, origin (-2, -1)."""
    g = np.ones((100, 120), np.uint8)
    g[[0, -1], :] = 2
    g[:, [0, -1]] = 2
    return save_ros_map(OccupancyMap(g, 0.1, origin=(-2.0, -1.0, 0.0), name="site"), root / "site.yaml")


def png_header_map(folder: Path, width: int, height: int, resolution: float) -> Path:
    """A ROS map yaml whose PNG's header claims ``width`` x ``height`` pixels (no need to hold them)."""
    import struct
    import zlib

    folder.mkdir(parents=True, exist_ok=True)

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    (folder / "big.png").write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr)
                                     + chunk(b"IDAT", zlib.compress(b"\x00" * 64)) + chunk(b"IEND", b""))
    yaml_path = folder / "big.yaml"
    yaml_path.write_text(f"image: big.png\nresolution: {resolution}\norigin: [0.0, 0.0, 0.0]\nnegate: 0\n"
                         "occupied_thresh: 0.65\nfree_thresh: 0.196\n")
    return yaml_path


def student(path: Path, role: str = "student", size: int = 64, resolution: float = 0.1,
            extra: dict[str, Any] | None = None) -> Path:
    """An untrained small student checkpoint as ``spade.train`` writes it (``extra``: more of its top level)."""
    import lightning
    import torch

    checkpoint = untrained_student("small", size, resolution)
    if role != "student":
        info = checkpoint["spade"]
        info["role"], info["config"] = role, {**info["config"], "role": "cond_expert"}
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save({**checkpoint, "pytorch-lightning_version": lightning.__version__,
                "hyper_parameters": {"size": "small"}, **(extra or {})}, path)
    return path


def onnx_material(root: Path, ckpt: Path) -> dict[str, Path]:
    """A real export of ``ckpt`` and its forgeries: an Identity graph with its metadata, a one-node graph without
    its integrity record, copies with ``resolution_m`` and the footprint edited."""
    import onnx
    from onnx import TensorProto, helper, numpy_helper

    real = export_student(ckpt, root / "student.onnx", "onnx", latency_runs=0).out_path
    meta = read_metadata(real)

    def graph(path: Path, metadata: dict, node: Any, inits: list, out_channels: int) -> Path:
        g = helper.make_graph([node], "forged",
                              [helper.make_tensor_value_info("state", TensorProto.FLOAT, ["N", 3, 64, 64])],
                              [helper.make_tensor_value_info("logits", TensorProto.FLOAT,
                                                             ["N", out_channels, 64, 64])], initializer=inits)
        model = helper.make_model(g, opset_imports=[helper.make_opsetid("", 17)])
        model.ir_version = 8
        entry = model.metadata_props.add()
        entry.key, entry.value = "spade", json.dumps(metadata)
        onnx.save(model, str(path))
        return path

    def edited(path: Path, metadata: dict) -> Path:
        model = onnx.load(str(real))
        next(e for e in model.metadata_props if e.key == "spade").value = json.dumps(metadata)
        onnx.save(model, str(path))
        return path

    unsigned = {k: v for k, v in meta.items() if k != "integrity"}
    consts = [numpy_helper.from_array(np.array([v], np.int64), n) for n, v in (("s", 0), ("e", 1), ("a", 1))]
    out = {"real_onnx": real,
           "identity_onnx": graph(root / "identity.onnx", meta, helper.make_node("Identity", ["state"], ["logits"]),
                                  [], 3),
           "unsigned_onnx": graph(root / "unsigned.onnx", unsigned,
                                  helper.make_node("Slice", ["state", "s", "e", "a"], ["logits"]), consts, 1)}
    for name, key, value in (("resolution_onnx", "resolution_m", 0.05),
                             ("footprint_onnx", "footprint", {"radius_m": 0.5, "inflation_radius_m": 0.55})):
        copy = json.loads(json.dumps(meta))
        copy["data"][key] = value
        out[name] = edited(root / f"{name}.onnx", copy)
    return out


def stores(root: Path) -> dict[str, Path]:
    """A store with a registered model of two versions, one with a finished quickstart run, one of another MLflow
    schema holding a run, a half-made one."""
    out = {}
    registry = root / "registry.db"
    ensure_store(f"sqlite:///{registry}")
    client = mlflow_client(f"sqlite:///{registry}")
    client.create_registered_model("stu")
    for _ in range(2):
        client.create_model_version("stu", source=str(root / "nowhere"))
    out["registry_db"] = registry
    trained = root / "trained.db"  # a store holding one finished row, as after make quickstart
    ensure_store(f"sqlite:///{trained}")
    client = mlflow_client(f"sqlite:///{trained}")
    run = client.create_run(client.create_experiment("quickstart"), run_name="quickstart", tags={"scale": "quickstart"})
    client.set_terminated(run.info.run_id, "FINISHED")
    out["trained_db"] = trained
    other = root / "other_schema.db"
    ensure_store(f"sqlite:///{other}")
    client = mlflow_client(f"sqlite:///{other}")
    client.create_run(client.create_experiment("old"))
    db = sqlite3.connect(other)
    db.execute("UPDATE alembic_version SET version_num='0123456789ab'")
    db.commit()
    db.close()
    out["other_schema_db"] = other
    half = root / "half.db"
    db = sqlite3.connect(half)
    db.execute("CREATE TABLE experiments (experiment_id INTEGER PRIMARY KEY, name VARCHAR(256))")
    db.execute("CREATE TABLE alembic_version (version_num VARCHAR(32) NOT NULL)")
    db.commit()
    db.close()
    out["half_db"] = half
    return out


def material(root: Path) -> dict[str, str]:
    """Every file the probes point at, under ``root``: placeholders for their arguments."""
    root.mkdir(parents=True, exist_ok=True)
    m: dict[str, Path] = {"map": site_map(root / "maps"), "model": student(root / "student.ckpt"),
                          "expert_as_student": student(root / "expert64.ckpt", role="expert"),
                          "eval_ckpt": student(root / "eval.ckpt", size=32, resolution=0.05),
                          "expert": student(root / "expert.ckpt", role="expert", size=32, resolution=0.05,
                                            extra={"hyper_parameters": {"num_train_timesteps": 50}}),
                          "test": dataset(root / "test"),
                          "nan_poses": poison(dataset(root / "nan_poses"), "pose", float("nan")),
                          "huge_waypoints": dataset(root / "huge_waypoints", waypoint_scale=1e30),
                          "big_map": png_header_map(root / "big", 20000, 20000, 0.05),
                          "coarse_map": png_header_map(root / "coarse", 1000, 1000, 5.0),
                          "dir": root / "a_folder", "file": root / "notes.txt", "missing": root / "missing.ckpt",
                          "tagged": root / "tagged.yaml"}
    m["dir"].mkdir(exist_ok=True)
    m["file"].write_text("not a model, not a map")
    m["tagged"].write_text("map: warehouse:1\nscenarios: !!python/object/apply:os.system ['echo pwned']\n")
    m.update(stores(root / "stores"))
    if all(importlib.util.find_spec(p) for p in ("onnx", "onnxruntime")):
        m.update(onnx_material(root / "onnx", m["model"]))
    return {k: str(v) for k, v in m.items()}


# -- probing ----------------------------------------------------------------------------------------------------------
def active_failed_runs(store: Path) -> int:
    """Runs of an SQLite store left FAILED and not deleted (0 when there is no store)."""
    if not store.is_file():
        return 0
    db = sqlite3.connect(store)
    try:
        return int(db.execute("SELECT COUNT(*) FROM runs WHERE status='FAILED' AND lifecycle_stage='active'")
                   .fetchone()[0])
    except sqlite3.DatabaseError:
        return 0
    finally:
        db.close()


def _home_store(work: Path) -> Path:
    return work / "home" / "logs" / "mlflow.db"


def left_failed_run(work: Path) -> str:
    return "a FAILED run" if active_failed_runs(_home_store(work)) else ""


def left_store(name: str) -> Callable[[Path], str]:
    return lambda work: f"a store {name}" if (work / name).exists() else ""


def made(name: str) -> Callable[[Path, int | None], bool]:
    """Acted on: the probe's output ``name`` (under its folder) was written."""
    return lambda work, rc: (work / name).exists()


def exited_0(work: Path, rc: int | None) -> bool:
    return rc == 0


@dataclass
class Probe:
    """One bad input: ``python -m <module> <args>`` (placeholders: the material's names and ``work``, the probe's
    folder) and how to read its outcome."""

    name: str
    cause: str  # the cause it tests, in the words of the reliability page
    module: str
    args: list[str]
    names: str = ""  # the key or file its error must name
    acted: Callable[[Path, int | None], bool] | None = None
    left: Callable[[Path], str] | None = left_failed_run
    needs: tuple[str, ...] = ()  # optional packages or material
    timeout: float = TIMEOUT_S
    hydra: bool = True  # a Hydra entry point (takes hydra.run.dir); False: a verifier's report (spade.data.verify)
    run: Callable[["Probe", Path, dict[str, str]], Outcome] | None = None  # a probe of its own (races, signals)


def environment(work: Path) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items()
           if k not in ("MLFLOW_TRACKING_URI", "MLFLOW_REGISTRY_URI", "HYDRA_FULL_ERROR", "SPADE_HOME")}
    return {**env, "SPADE_HOME": str(work / "home"), "OMP_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1",
            "PYTHONPATH": os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)}


PLACEHOLDER = re.compile(r"\{(\w+)\}")  # {name}; YAML's {table: x} is left as it is


def fill(arg: str, values: dict[str, str]) -> str:
    return PLACEHOLDER.sub(lambda match: values.get(match.group(1), match.group(0)), arg)


def command(probe: Probe, work: Path, m: dict[str, str]) -> list[str]:
    args = [fill(a, {**m, "work": str(work)}) for a in probe.args]
    return [sys.executable, "-m", probe.module, *args]


def run_process(cmd: list[str], work: Path, timeout: float) -> tuple[int | None, str, float]:
    """Run ``cmd`` in ``work`` (its own process group, killed whole at ``timeout``): status, output, seconds."""
    start = time.monotonic()
    with tempfile.TemporaryFile("w+") as sink:
        proc = subprocess.Popen(cmd, cwd=work, env=environment(work), stdout=sink, stderr=subprocess.STDOUT,
                                start_new_session=True)
        try:
            rc: int | None = proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
            rc = None
        sink.seek(0)
        return rc, sink.read(), time.monotonic() - start


def run_probe(probe: Probe, work: Path, m: dict[str, str]) -> Outcome:
    work.mkdir(parents=True, exist_ok=True)
    if probe.run is not None:
        return probe.run(probe, work, m)
    rc, output, seconds = run_process(command(probe, work, m), work, probe.timeout)
    acted = bool(probe.acted and probe.acted(work, rc))
    left = probe.left(work) if probe.left else ""
    return Outcome(rc, output, acted, left, seconds)


# -- probes of their own: a race, an interrupt, a saved sketch, a busy port -------------------------------------------
def race(probe: Probe, work: Path, m: dict[str, str]) -> Outcome:
    """Two evaluations and an ``export register=`` started together on a fresh store: all must run. Acted on
    nothing: a crash is unclear."""
    env = environment(work)
    cmds = [[sys.executable, "-m", "spade.evaluate", f"ckpt_path={m['eval_ckpt']}", "data=own",
             f"data.test_dir={m['test']}", "data.test_shape=null", f"seed={seed}"] for seed in (1, 2)]
    cmds.append([sys.executable, "-m", "spade.export", f"ckpt_path={m['model']}", "latency_runs=0",
                 f"out_path={work / 'raced.onnx'}", "register=spade-student"])
    start = time.monotonic()
    sinks = [open(work / f"race{i}.txt", "w") for i in range(len(cmds))]
    procs = [subprocess.Popen(c, cwd=work, env=env, stdout=s, stderr=subprocess.STDOUT, start_new_session=True)
             for c, s in zip(cmds, sinks)]
    codes: list[int | None] = []
    for proc in procs:
        try:
            codes.append(proc.wait(timeout=max(1.0, probe.timeout - (time.monotonic() - start))))
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
            codes.append(None)
    for s in sinks:
        s.close()
    outputs = [(work / f"race{i}.txt").read_text() for i in range(len(cmds))]
    failed = [i for i, c in enumerate(codes) if c != 0]
    if not failed:  # a valid input that ran: clear, by an exit status of 1 and its one line
        return Outcome(0, "", ok=True, seconds=time.monotonic() - start)
    i = failed[0]
    return Outcome(codes[i], outputs[i], seconds=time.monotonic() - start)


def interrupt(probe: Probe, work: Path, m: dict[str, str]) -> Outcome:
    """Ctrl-C while ``spade.evaluate`` creates a fresh store, then the same evaluation again: the second must run
    (or say what to fix)."""
    cmd = [sys.executable, "-m", "spade.evaluate", f"ckpt_path={m['eval_ckpt']}", "data=own",
           f"data.test_dir={m['test']}", "data.test_shape=null"]
    logs = work / "home" / "logs"
    start = time.monotonic()
    proc = subprocess.Popen(cmd, cwd=work, env=environment(work), stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    while proc.poll() is None and time.monotonic() - start < probe.timeout:
        if logs.is_dir() and any(p.name.endswith(".db") or ".partial" in p.name for p in logs.iterdir()):
            break
        time.sleep(0.005)
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    try:
        proc.wait(timeout=60)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    rc, output, _ = run_process(cmd, work, probe.timeout)
    if rc == 0:
        return Outcome(0, "", ok=True, seconds=time.monotonic() - start)
    return Outcome(rc, output, seconds=time.monotonic() - start)


def sketch_mode(probe: Probe, work: Path, m: dict[str, str]) -> Outcome:
    """A sketch saved through the app into a ``sketches.yaml`` of mode 644: the file's mode kept."""
    script = (
        "import os, stat, sys\n"
        "from pathlib import Path\n"
        "from fastapi.testclient import TestClient\n"
        "from spade.sketching import build_app\n"
        "out = Path(sys.argv[2])\n"
        "TINY = ['window.size_px=64', 'window.resolution_m=0.1', 'instances.spacing_m=0.15', 'preview.count=4']\n"
        "client = TestClient(build_app(sys.argv[1], out, TINY), base_url='http://127.0.0.1:8765')\n"
        "wp = [[0.0, 1.0], [1.5, 1.0], [2.5, 1.0], [3.1, 1.3], [3.4, 2.0], [3.4, 3.0]]\n"
        "for i in range(2):\n"
        "    r = client.post('/api/sketches', json={'shape': 'L', 'waypoints': wp})\n"
        "    assert r.status_code in (200, 201), r.text\n"
        "    if i == 0: (out / 'sketches.yaml').chmod(0o644)\n"
        "mode = stat.S_IMODE((out / 'sketches.yaml').stat().st_mode)\n"
        "print(f'error: sketches.yaml mode {mode:o} after a save; the file kept its mode' if mode == 0o644 else\n"
        "      f'sketches.yaml reset to mode {mode:o} by a save')\n"
        "sys.exit(1 if mode == 0o644 else 0)\n")
    rc, output, seconds = run_process([sys.executable, "-c", script, m["map"], str(work / "sk")], work, probe.timeout)
    return Outcome(rc, output, seconds=seconds)


def busy_port(probe: Probe, work: Path, m: dict[str, str]) -> Outcome:
    """The simulator's Foxglove server asked for a port another program holds."""
    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        held.listen(1)
        port = held.getsockname()[1]
        cmd = [sys.executable, "-m", "spade.ros", "sim", "map=warehouse:1", "foxglove=true",
               f"foxglove_port={port}", "max_seconds=5", f"hydra.run.dir={work / 'hydra'}"]
        rc, output, seconds = run_process(cmd, work, probe.timeout)
    return Outcome(rc, output, seconds=seconds)


# -- the probes -------------------------------------------------------------------------------------------------------
PLAN = ["map={map}", "start=[0.0,1.0,0.0]", "goal=[2.0,1.0]", "out={work}/plan.png"]
EVAL = ["ckpt_path={eval_ckpt}", "data=own", "data.test_dir={test}", "data.test_shape=null"]
CRITIC = ["ckpt_path={expert}", "data.test_dir={test}", "data.test_shape=null", "output_dir={work}/out"]
CL = ["tracking_uri=sqlite:///{work}/mlflow.db"]
ONNX = ("onnx", "onnxruntime")
plan_made = made("plan.png")


def P(*args: Any, **kwargs: Any) -> Probe:  # noqa: N802 - a table row
    return Probe(*args, **kwargs)


PROBES: list[Probe] = [
    # model files trusted as far as they are signed
    P("plan-forged-identity", "a forged model", "spade.plan", [*PLAN, "model_path={identity_onnx}"], "identity.onnx",
      plan_made, needs=ONNX),
    P("plan-unsigned-graph", "a forged model", "spade.plan", [*PLAN, "model_path={unsigned_onnx}"], "unsigned.onnx",
      plan_made, needs=ONNX),
    P("plan-edited-resolution", "an edited model field", "spade.plan", [*PLAN, "model_path={resolution_onnx}"],
      "resolution_m", plan_made, needs=ONNX),
    P("plan-edited-footprint", "an edited model field", "spade.plan", [*PLAN, "model_path={footprint_onnx}"],
      "footprint", plan_made, needs=ONNX),
    P("sketch-forged-start", "a forged model at the sketch app's start", "spade.sketch",
      ["map={map}", "out_dir={work}/sk", "model_path={unsigned_onnx}", "port=18765"], "unsigned.onnx",
      lambda work, rc: rc is None, needs=ONNX, timeout=90),
    P("ros-unsigned", "a forged model", "spade.ros", ["model_path={unsigned_onnx}"], "unsigned.onnx",
      lambda work, rc: rc is None, needs=(*ONNX, "cyclonedds"), timeout=60),
    # poisoned and absurd data
    P("verify-nan-poses", "absurd data", "spade.data.verify", ["{nan_poses}"], "pose", exited_0, hydra=False),
    P("verify-huge-waypoints", "absurd data", "spade.data.verify", ["{huge_waypoints}"], "waypoints", exited_0,
      hydra=False),
    P("evaluate-nan-poses", "absurd data", "spade.evaluate", [*EVAL[:2], "data.test_dir={nan_poses}",
                                                               "data.test_shape=null"], "pose", exited_0),
    P("evaluate-huge-waypoints", "absurd data", "spade.evaluate",
      [*EVAL[:2], "data.test_dir={huge_waypoints}", "data.test_shape=null"], "waypoints", exited_0),
    P("critic-huge-waypoints", "absurd data", "spade.critic",
      [*CRITIC[:1], "data.test_dir={huge_waypoints}", *CRITIC[2:]], "waypoints", exited_0),
    # spade.closed_loop's preflight
    P("closed-loop-source-without-row", "closed-loop preflight", "spade.closed_loop",
      ["sources=[{table: guidance}]", *CL], "sources[0]", left=left_store("mlflow.db")),
    P("closed-loop-quote-in-row", "closed-loop preflight", "spade.closed_loop",
      ["sources=[{table: guidance, row: \"a'b\"}]", *CL], "sources[0].row", left=left_store("mlflow.db")),
    P("closed-loop-sources-string", "closed-loop preflight", "spade.closed_loop", ["sources=guidance", *CL],
      "sources", left=left_store("mlflow.db")),
    P("closed-loop-unknown-table", "closed-loop preflight", "spade.closed_loop",
      ["sources=[{table: nosuch, row: t1_small_bc_L}]", "tracking_uri=sqlite:///{trained_db}"], "nosuch"),
    P("closed-loop-scenarios-0", "closed-loop preflight", "spade.closed_loop", ["datasets.heldout.scenarios=0", *CL],
      "datasets.heldout.scenarios", left=left_store("mlflow.db")),
    P("closed-loop-negative-noise", "closed-loop preflight", "spade.closed_loop",
      ["conditions.perturbed.noise_xy_m=-0.1", *CL], "noise_xy_m", left=left_store("mlflow.db")),
    P("closed-loop-misspelt-setting", "closed-loop preflight", "spade.closed_loop",
      ["+conditions.perturbed.nois_xy_m=0.1", *CL], "nois_xy_m", left=left_store("mlflow.db")),
    P("closed-loop-mistyped-store", "closed-loop preflight", "spade.closed_loop",
      ["tracking_uri=sqlite:///{work}/mlfow.db"], "mlfow.db", left=left_store("mlfow.db")),
    # spade.evaluate's drive.* options
    P("drive-scenarios-0", "drive.* options", "spade.evaluate", [*EVAL, "closed_loop=true", "drive.scenarios=0"],
      "drive.scenarios"),
    P("drive-baselines-string", "drive.* options", "spade.evaluate",
      [*EVAL, "closed_loop=true", "drive.baselines=shortest"], "drive.baselines"),
    P("drive-negative-commit-tol", "drive.* options", "spade.evaluate",
      [*EVAL, "closed_loop=true", "drive.commit_tol_cm=-1"], "drive.commit_tol_cm"),
    P("drive-mcap-episodes", "drive.* options", "spade.evaluate", [*EVAL, "closed_loop=true", "drive.mcap_episodes=-3"],
      "drive.mcap_episodes"),
    P("drive-speed-0", "drive.* options", "spade.evaluate", [*EVAL, "closed_loop=true", "drive.follower.speed_mps=0"],
      "drive.follower.speed_mps"),
    P("evaluate-nothing", "drive.* options", "spade.evaluate", [*EVAL, "open_loop=false", "closed_loop=false"],
      "open_loop"),
    # a refusal leaves no FAILED run
    P("evaluate-empty-shape", "a refusal leaves no FAILED run", "spade.evaluate",
      [*EVAL[:3], "data.test_shape=Z"], "data.test_shape"),
    P("evaluate-source-seed", "a refusal leaves no FAILED run", "spade.evaluate", [*EVAL, "source_seed=abc"],
      "source_seed"),
    # the store
    P("store-race", "a store race", "spade.evaluate", [], timeout=300, run=race, needs=ONNX),
    P("store-interrupt", "Ctrl-C during store creation", "spade.evaluate", [], timeout=180, run=interrupt),
    P("store-half-made", "Ctrl-C during store creation", "spade.evaluate",
      [*EVAL, "paths.mlflow_tracking_uri=sqlite:///{half_db}"], "half.db"),
    P("store-other-schema", "another MLflow schema", "spade.evaluate",
      [*EVAL, "paths.mlflow_tracking_uri=sqlite:///{other_schema_db}"], "other_schema.db"),
    P("report-other-schema", "another MLflow schema", "spade.report",
      ["table=table1", "tracking_uri=sqlite:///{other_schema_db}", "output_dir={work}/rep"], "other_schema.db"),
    P("registry-missing-version", "a missing registry version", "spade.plan",
      [*PLAN, "model_path=models:/stu/99", "paths.mlflow_tracking_uri=sqlite:///{registry_db}"], "models:/stu/99",
      plan_made),
    P("registry-missing-name", "a missing registry version", "spade.plan",
      [*PLAN, "model_path=models:/other/1", "paths.mlflow_tracking_uri=sqlite:///{registry_db}"], "other",
      plan_made),
    # Lightning's errors through Hydra
    P("train-accelerator", "Lightning errors through Hydra", "spade.train",
      ["+experiment=t1_small_bc_L", "scale=tiny", "logger=none", "trainer.accelerator=tpu"], "trainer.accelerator",
      timeout=180),
    P("train-precision", "Lightning errors through Hydra", "spade.train",
      ["+experiment=t1_small_bc_L", "scale=tiny", "logger=none", "trainer.precision=banana"], "trainer.precision",
      timeout=180),
    P("train-devices", "Lightning errors through Hydra", "spade.train",
      ["+experiment=t1_small_bc_L", "scale=tiny", "logger=none", "trainer.devices=-7"], "trainer.devices",
      timeout=180),
    # read-only folders
    P("plan-read-only-logs", "read-only log folders", "spade.plan",
      [*PLAN, "model_path={model}", "paths.log_dir={work}/ro/logs"], "ro", plan_made, needs=("not-root",),
      hydra=False),
    # map specs and huge maps
    P("plan-warehouse-abc", "warehouse:abc", "spade.plan", ["map=warehouse:abc", *PLAN[1:], "model_path={model}"],
      "warehouse:abc", plan_made),
    P("annotate-warehouse-abc", "warehouse:abc", "spade.annotate",
      ["maps=[warehouse:abc]", "num_instances=5", "out_dir={work}/ds"], "warehouse:abc", made("ds")),
    P("sketch-warehouse-abc", "warehouse:abc", "spade.sketch", ["map=warehouse:abc", "out_dir={work}/sk"],
      "warehouse:abc", lambda work, rc: rc is None, timeout=60),
    P("annotate-huge-map", "huge maps", "spade.annotate", ["maps=[{big_map}]", "num_instances=2", "out_dir={work}/ds"],
      "big.yaml", made("ds")),
    P("annotate-coarse-map", "huge maps", "spade.annotate",
      ["maps=[{coarse_map}]", "num_instances=2", "out_dir={work}/ds"], "big.yaml", made("ds")),
    P("plan-huge-map", "huge maps", "spade.plan", ["map={big_map}", *PLAN[1:], "model_path={model}"], "big.yaml",
      plan_made),
    # the critic
    P("critic-t-max", "critic.t_max beyond the expert", "spade.critic", [*CRITIC, "model.margin.t_max=80"],
      "model.margin.t_max", left=left_store("out")),
    P("critic-bands", "critic.bands=100000", "spade.critic", [*CRITIC, "critic.bands=100000"], "critic.bands",
      left=left_store("out"), timeout=90),
    P("critic-student-as-expert", "critic inputs", "spade.critic", [*CRITIC[1:], "ckpt_path={eval_ckpt}"],
      "ckpt_path", left=left_store("out")),
    # the simulator and Foxglove
    P("sim-busy-port", "Foxglove on a busy port", "spade.ros", [], "port", timeout=90, run=busy_port,
      needs=("foxglove", "cyclonedds")),
    P("sim-empty-host", "Foxglove on an empty host", "spade.ros",
      ["sim", "map=warehouse:1", "foxglove=true", "foxglove_host=''", "max_seconds=5"], "foxglove_host",
      needs=("foxglove", "cyclonedds"), timeout=90),
    P("sim-missing-map", "the simulator's bad maps and ranges", "spade.ros", ["sim", "map={missing}.yaml",
                                                                             "max_seconds=5"], "missing",
      needs=("cyclonedds",), timeout=90),
    P("sim-rate-0", "the simulator's bad maps and ranges", "spade.ros",
      ["sim", "map=warehouse:1", "rate_hz=0", "max_seconds=5"], "rate_hz", needs=("cyclonedds",), timeout=90),
    P("sim-goal-distance", "the simulator's bad maps and ranges", "spade.ros",
      ["sim", "map=warehouse:1", "goal_distance_m=[3.0,1.0]", "max_seconds=5"], "goal_distance_m",
      needs=("cyclonedds",), timeout=90),
    P("sim-speed-negative", "the simulator's bad maps and ranges", "spade.ros",
      ["sim", "map=warehouse:1", "speed_mps=-1", "max_seconds=5"], "speed_mps", needs=("cyclonedds",), timeout=90),
    # the sketch app
    P("sketch-mode", "sketches.yaml mode 600", "spade.sketch", [], "", run=sketch_mode, needs=("fastapi", "httpx")),
    # inputs every entry point checks (a sample of the earlier rounds' probes)
    P("annotate-instances-0", "inputs", "spade.annotate", ["num_instances=0", "out_dir={work}/ds"], "num_instances",
      made("ds")),
    P("annotate-tagged-sketch", "inputs", "spade.annotate", ["sketches={tagged}", "out_dir={work}/ds"], "tagged.yaml",
      made("ds")),
    P("annotate-radius", "inputs", "spade.annotate",
      ["maps=[warehouse:1]", "num_instances=2", "robot.radius_m=-1", "out_dir={work}/ds"], "robot.radius_m",
      made("ds")),
    P("evaluate-folder-ckpt", "inputs", "spade.evaluate", ["ckpt_path={dir}"], "a_folder"),
    P("evaluate-text-ckpt", "inputs", "spade.evaluate", ["ckpt_path={file}"], "notes.txt"),
    P("plan-expert", "inputs", "spade.plan", [*PLAN, "model_path={expert_as_student}"], "expert", plan_made),
    P("plan-start-is-goal", "inputs", "spade.plan",
      ["map={map}", "start=[0.0,1.0,0.0]", "goal=[0.0,1.0]", "model_path={model}", "out={work}/plan.png"], "goal",
      plan_made),
    P("plan-nan-start", "inputs", "spade.plan",
      ["map={map}", "start=[nan,1.0,0.0]", "goal=[2.0,1.0]", "model_path={model}", "out={work}/plan.png"], "start",
      plan_made),
    P("export-tflite", "inputs", "spade.export", ["ckpt_path={model}", "format=tflite", "out_path={work}/m.onnx"],
      "format", made("m.onnx")),
    P("export-latency-0", "inputs", "spade.export", ["ckpt_path={model}", "latency_batches=[0]",
                                                     "out_path={work}/m.onnx"], "latency_batches", made("m.onnx")),
    P("train-promote-maybe", "inputs", "spade.train", ["+experiment=t1_small_bc_L", "registry.promote=maybe"],
      "registry.promote", timeout=180),
    P("train-unknown-experiment", "inputs", "spade.train", ["+experiment=nosuch"], "nosuch"),
    P("report-unknown-table", "inputs", "spade.report", ["table=table9", "output_dir={work}/rep"], "table9"),
    P("bench-quick-maybe", "inputs", "spade.bench", ["quick=maybe", "out_json={work}/b.json"], "quick",
      made("b.json")),
    P("verify-text-file", "inputs", "spade.data.verify", ["{file}"], "notes.txt", hydra=False),
]


def skip_reason(probe: Probe, m: dict[str, str]) -> str:
    for need in probe.needs:
        if need == "not-root":
            if os.geteuid() == 0:
                return "run as root, which writes into read-only folders"
        elif importlib.util.find_spec(need) is None:
            return f"needs {need}, not installed"
    missing = sorted({name for a in probe.args for name in PLACEHOLDER.findall(a)} - set(m) - {"work"})
    return f"needs {', '.join(missing)}, not made on this machine" if missing else ""


def prepare(probe: Probe, work: Path) -> None:
    """What a probe needs in its folder before it runs (a read-only log folder)."""
    if probe.name == "plan-read-only-logs":
        ro = work / "ro"
        ro.mkdir(parents=True, exist_ok=True)
        ro.chmod(0o555)


def probe_all(out: Path, only: list[str] | None = None) -> dict[str, Any]:
    start = time.monotonic()
    rows = []
    with tempfile.TemporaryDirectory(prefix="spade-probes-") as tmp:
        root = Path(tmp)
        m = material(root / "material")
        for i, probe in enumerate(p for p in PROBES if not only or p.name in only):
            work = root / f"{i:02d}_{probe.name}"
            row = {"name": probe.name, "cause": probe.cause, "module": probe.module}
            reason = skip_reason(probe, m)
            if reason:
                rows.append({**row, "verdict": "skipped", "why": reason})
                print(f"{probe.name}: skipped ({reason})", flush=True)
                continue
            work.mkdir(parents=True)
            prepare(probe, work)
            if probe.run is None:
                args = list(probe.args) + ([f"hydra.run.dir={work / 'hydra'}"] if probe.hydra else [])
                probe = Probe(**{**probe.__dict__, "args": args})
            outcome = run_probe(probe, work, m)
            verdict, why = classify(outcome, probe.names, report=not probe.hydra and probe.module == "spade.data.verify")
            shown = _scrubbed(" ".join(command(probe, work, m)[2:]), root, work)
            errors = error_lines(outcome.output)
            rows.append({**row, "command": "python -m " + shown if probe.run is None else probe.run.__doc__.split(
                ":")[0].strip().replace("\n", " ").replace("    ", " "),
                "rc": outcome.rc, "seconds": round(outcome.seconds, 1), "verdict": verdict, "why": why,
                "error": _scrubbed(errors[0], root) if errors else "",
                "tail": "" if verdict == "clear" else _scrubbed(outcome.output[-600:], root)})
            print(f"{probe.name}: {verdict} {why} ({outcome.seconds:.0f} s)", flush=True)
            (work / "ro").chmod(0o755) if (work / "ro").exists() else None
    counts = {v: sum(r["verdict"] == v for r in rows) for v in (*VERDICTS, "skipped")}
    record = {"command": "python -m spade.perf.hostile_probes " + str(out), "commit": commit(),
              "date": f"{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC", "machine": machine(),
              "wall_s": round(time.monotonic() - start), "counts": counts, "probes": rows}
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(record, indent=1) + "\n")
    return record


# -- the page ---------------------------------------------------------------------------------------------------------
def _cell(text: str) -> str:
    return " ".join(str(text).split()).replace("|", "\\|")


def render_section(record: dict[str, Any]) -> str:
    """The reliability page's section on the probes, from their record: provenance, counts, and each probe that was
    not clear (unclear, wrong or skipped) with why."""
    c = record["counts"]
    lines = [BEGIN, "", f"- command: `{record['command']}`", f"- commit: {record['commit']}",
             f"- date: {record['date']}", f"- machine: {record['machine']}",
             f"- wall time: {record['wall_s']} s", "",
             f"{sum(c[v] for v in VERDICTS)} probes run: **{c['clear']} clear, {c['unclear']} unclear, "
             f"{c['wrong']} wrong**; {c['skipped']} skipped.", ""]
    rest = [r for r in record["probes"] if r["verdict"] != "clear"]
    if rest:
        lines += ["| probe | cause | verdict | why |", "|---|---|---|---|"]
        lines += [f"| `{r['name']}` | {_cell(r['cause'])} | {r['verdict']} | {_cell(r['why'])} |" for r in rest]
        lines.append("")
    lines.append(END)
    return "\n".join(lines)


def update_page(record: dict[str, Any], page: Path = PAGE) -> None:
    """Replace the page's generated section (between its markers) with :func:`render_section`'s."""
    text = page.read_text()
    head, _, rest = text.partition(BEGIN)
    _, _, tail = rest.partition(END)
    if not rest:
        raise ValueError(f"{page} has no {BEGIN} marker")
    page.write_text(head + render_section(record) + tail)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m spade.perf.hostile_probes", description=__doc__.split("\n")[0])
    parser.add_argument("out", type=Path, nargs="?", default=RECORD, help="the record (JSON) to write")
    parser.add_argument("--only", nargs="*", help="run only these probes (by name)")
    parser.add_argument("--page", action="store_true", help="write the section of docs/reference/reliability.md")
    args = parser.parse_args(argv)
    record = probe_all(args.out, args.only)
    if args.page:
        update_page(record)
    print(json.dumps(record["counts"]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
