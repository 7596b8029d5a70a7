"""The sketching app's JSON API (FastAPI TestClient): execute / save / list / delete round trips, dataset builds,
the planner, every bad request (4xx with a message, the sketch file untouched) and saves racing."""

from __future__ import annotations

import hashlib
import json
import re
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

pytest.importorskip("fastapi")
pytest.importorskip("httpx")
from fastapi.testclient import TestClient  # noqa: E402

from spade.annotation.sketch_file import load_sketch_file  # noqa: E402
from spade.sketching import build_app  # noqa: E402
from spade.sketching.app import STATIC_DIR  # noqa: E402
from factories import LineOracle, site_map  # noqa: E402
from factories import LOCAL, L_WAYPOINTS, TINY

L_SECOND = [[0.0, 6.0], [1.5, 6.0], [2.3, 6.0], [2.9, 6.3], [3.2, 7.0], [3.2, 8.0]]
BLOCK = [4.0, 4.0]  # the middle of the site's obstacle


@pytest.fixture
def setup(tmp_path: Path) -> tuple[TestClient, Path, Path]:
    """(client, map yaml, out_dir) of an app on the site map."""
    yaml_path = site_map(tmp_path, block=True)
    out = tmp_path / "out"
    return TestClient(build_app(str(yaml_path), out, TINY), base_url=LOCAL), yaml_path, out


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest() if path.exists() else "absent"


def student_checkpoint(path: Path, role: str = "student", footprint: dict | None = None) -> Path:
    """A checkpoint as spade.train writes it (untrained small student), without training."""
    import torch

    from spade.models.builders import build_model

    from spade.maps.frame import RobotFrame

    net = build_model("student", "small")
    info = {"role": role, "config": dict(net.config),
            "data": {"image_size": [64, 64], "resolution_m": 0.1, "frame": RobotFrame.for_size(64).to_json()}}
    if footprint:
        info["data"]["footprint"] = footprint
    torch.save({"spade": info, "state_dict": {f"net.{k}": v for k, v in net.state_dict().items()}}, path)
    return path


# ------------------------------------------------------------------------------------------------ the page and map
def test_map_metadata_images_and_a_self_contained_page(setup) -> None:
    client, yaml_path, out = setup
    meta = client.get("/api/map").json()
    assert meta["map"] == str(yaml_path.resolve()) and meta["map_id"] == "site"
    assert (meta["width_px"], meta["height_px"], meta["resolution"]) == (120, 100, 0.1)
    assert meta["bounds_m"] == pytest.approx({"x_min": -2.0, "y_min": -1.0, "x_max": 10.0, "y_max": 9.0})
    assert meta["shapes"] == ["L", "U"] and meta["model"] is None
    assert meta["sketch_file"] == str(out.resolve() / "sketches.yaml")
    assert "window.size_px=64" in meta["build_command"]
    from io import BytesIO

    from PIL import Image

    assert Image.open(BytesIO(client.get("/api/map.png").content)).size == (120, 100)
    overlay = Image.open(BytesIO(client.get("/api/costmap.png").content))
    assert overlay.size == (120, 100) and overlay.mode == "RGBA"
    alpha = np.asarray(overlay)[..., 3]
    assert alpha[50, 30] == 0 and alpha[50, 54] > 0  # open floor clear, the band around the block tinted
    assert client.get("/api/openapi.json").json()["paths"]["/api/execute"]["post"]
    page = client.get("/")
    assert page.status_code == 200 and "/static/app.js" in page.text
    for name in ("app.js", "style.css"):
        assert client.get(f"/static/{name}").status_code == 200
    for path in STATIC_DIR.iterdir():  # no CDN: nothing the page loads comes from elsewhere
        assert not re.search(r"(src|href)=[\"']?(https?:)?//|import\s.*https?:|url\(\s*[\"']?https?:",
                             path.read_text()), path


# ------------------------------------------------------------------------------------------------ execute
def test_execute_accepts_an_l_and_gives_the_executed_path_in_metres(setup) -> None:
    client, _, _ = setup
    r = client.post("/api/execute", json={"shape": "L", "waypoints": L_WAYPOINTS})
    assert r.status_code == 200, r.text
    res = r.json()
    assert res["accepted"], res["message"]
    path = np.asarray(res["path"])
    assert np.linalg.norm(path[0] - L_WAYPOINTS[0]) < 0.1 and np.linalg.norm(path[-1] - L_WAYPOINTS[-1]) < 0.1
    assert 60 < abs(res["turn_deg"]) < 120 and res["deviation_m"] < 0.35 and res["length_m"] > 4.0


@pytest.mark.parametrize("shape, waypoints, reason, words", [
    ("U", [[0.0, 1.0], [4.0, 1.0]], "shape", "does not turn like the shape"),
    ("L", [[2.0, 4.0], BLOCK, [4.0, 6.0]], "sketch_off_free", "waypoint #2"),
    ("L", [[2.0, 4.0], [6.0, 4.0], [6.0, 6.0]], "deviation", "strays too far from the sketch"),
])
def test_execute_rejections_in_words_with_the_offending_part(setup, shape, waypoints, reason, words) -> None:
    client, _, out = setup
    res = client.post("/api/execute", json={"shape": shape, "waypoints": waypoints}).json()
    assert not res["accepted"] and res["reason"] == reason and words in res["message"], res
    if reason == "sketch_off_free":
        assert res["offending_waypoints"] == [1]
    else:
        assert res["path"] and res["offending"]  # the driven path and its offending points, in metres
    assert not (out / "sketches.yaml").exists()


WIDE = [[0.0, 1.0], [1.2, 1.0], [1.8, 1.0], [2.3, 1.3], [2.6, 2.0], [2.6, 4.6]]  # its goal 3.6 m to the left


def test_the_window_fit_moves_with_the_sketch_and_names_the_waypoints_outside(setup) -> None:
    """The window the page draws (robot at the first waypoint, heading along the sketch) decides the fit: the same
    sketch shifted by centimetres gets the same verdict and the same window, shifted; a rejection names the
    waypoints outside it (numbered from 1), not every point."""
    client, _, _ = setup
    window = client.get("/api/map").json()["window"]
    assert window["robot_px"] == [32.0, 48.0] and window["heading_m"] > 0 and window["path_margin_m"] > 0
    base = None
    for dx, dy in ((0.0, 0.0), (0.02, 0.0), (0.0, -0.02), (-0.014, 0.014), (0.05, 0.03), (0.01, 0.04)):
        shift = np.array([dx, dy])
        res = client.post("/api/execute", json={"shape": "L", "waypoints": (L_WAYPOINTS + shift).tolist()}).json()
        assert res["accepted"], (dx, dy, res["message"])
        corners = np.asarray(res["window"]["corners_m"])
        base = corners if base is None else base
        np.testing.assert_allclose(corners - shift, base, atol=2e-3)
        wide = client.post("/api/execute", json={"shape": "L", "waypoints": (WIDE + shift).tolist()}).json()
        assert not wide["accepted"] and wide["reason"] == "window", (dx, dy, wide["message"])
        assert wide["offending_waypoints"] == [5] and "waypoint #6" in wide["message"], wide["message"]
        assert "#5" not in wide["message"] and len(wide["offending"]) < len(wide["path"]) / 4
    # the window is 6.4 m wide, its corners 6.4 m apart; the margin's rectangle lies inside it
    assert abs(np.linalg.norm(base[1] - base[0]) - 6.4) < 1e-6


@pytest.mark.parametrize("slack_m", [0.01, -0.01])
def test_a_sketch_at_the_margin_keeps_its_verdict_under_2_cm_shifts(setup, slack_m: float) -> None:
    """A goal 1 cm inside (outside) the window's margin: every shift of the whole sketch by up to 2 cm, in any
    direction, gets the same verdict from the server, and the verdict is the rule's the page computes from the
    numbers GET /api/map serves (waypoints margin_m inside the window placed by the sketch)."""
    client, _, _ = setup
    rule = client.get("/api/map").json()["window"]
    assert rule["tolerance_m"] >= 0.02 + rule["resolution_m"] - 1e-9
    # an L heading +x from (-1, 0): its window's left margin lies size/2 - margin cells to its left
    lateral = (rule["robot_px"][0] - rule["margin_m"] / rule["resolution_m"]) * rule["resolution_m"]
    sketch = np.array([[-1.0, 0.0], [0.5, 0.0], [1.5, 0.0], [2.1, 0.3], [2.4, 1.0], [2.4, 2.0]])
    sketch[-1, 1] = sketch[0, 1] + lateral - slack_m
    verdicts = set()
    for angle in np.linspace(0, 2 * np.pi, 6, endpoint=False):
        for r in (0.005, 0.01, 0.015, 0.02):
            shift = r * np.array([np.cos(angle), np.sin(angle)])
            res = client.post("/api/execute", json={"shape": "L", "waypoints": (sketch + shift).tolist()}).json()
            verdicts.add((res["accepted"], res.get("reason"), res["window"]["fits"],
                          tuple(res["window"]["outside_waypoints"])))
    expected = (True, None, True, ()) if slack_m > 0 else (False, "window", False, (5,))
    assert verdicts == {expected}, verdicts


@pytest.mark.parametrize("waypoints, words", [([], "the sketch has 0 waypoints"),
                                              ([[0.0, 1.0]], "the sketch has 1 waypoint:")])
def test_execute_and_save_need_waypoints(setup, waypoints, words) -> None:
    client, _, out = setup
    for url in ("/api/execute", "/api/sketches"):
        r = client.post(url, json={"shape": "L", "waypoints": waypoints})
        assert r.status_code == 422 and r.json()["error"].startswith(words), r.text
        assert "\n" not in r.json()["error"] and "at least 2" in r.json()["error"]
    assert not (out / "sketches.yaml").exists()


def test_a_waypoint_outside_the_map_is_named_from_1_and_marked(setup) -> None:
    client, _, _ = setup
    res = client.post("/api/execute", json={"shape": "L", "waypoints": [[0.0, 1.0], [15.0, 1.0], [3.0, 3.0]]})
    assert res.status_code == 200, res.text
    res = res.json()
    assert not res["accepted"] and res["reason"] == "sketch_off_map" and res["offending_waypoints"] == [1]
    assert "waypoint #2 (15.00, 1.00) m lies outside map 'site'" in res["message"], res["message"]
    assert "x [-2.00, 10.00] m" in res["message"]
    off_free = client.post("/api/execute", json={"shape": "L", "waypoints": [[2.0, 4.0], BLOCK, [4.0, 6.0]]}).json()
    assert "waypoint #2" in off_free["message"] and off_free["offending_waypoints"] == [1]  # the same numbering


def test_the_page_gets_the_palette_and_the_footprint(setup, tmp_path: Path) -> None:
    from spade.utils import palette

    client, _, _ = setup
    meta = client.get("/api/map").json()
    assert meta["palette"]["prediction"] == palette.PREDICTION and meta["palette"]["robot"] == palette.ROBOT
    assert meta["footprint"]["source"] == "settings" and meta["footprint"]["radius_m"] == meta["robot"]["radius_m"]
    # a model that records its footprint: the page draws the model's, and says it differs from the settings'
    ckpt = student_checkpoint(tmp_path / "out" / "wide_robot.ckpt", footprint={"radius_m": 0.3,
                                                                             "inflation_radius_m": 0.4})
    loaded = client.post("/api/model", json={"path": str(ckpt)})
    assert loaded.status_code == 200, loaded.text
    shown = loaded.json()["model"]["footprint"]
    assert (shown["source"], shown["radius_m"], shown["inflation_radius_m"]) == ("model", 0.3, 0.4)
    assert shown["differs_from_settings"] and shown["settings"]["radius_m"] == meta["robot"]["radius_m"]
    assert client.get("/api/map").json()["footprint"] == shown


# ------------------------------------------------------------------------------------------------ save, list, delete
def test_save_list_delete_round_trip_and_restart(setup) -> None:
    client, yaml_path, out = setup
    t0 = time.perf_counter()
    r = client.post("/api/sketches", json={"shape": "L", "waypoints": L_WAYPOINTS})
    save_s = time.perf_counter() - t0
    assert r.status_code == 201, r.text
    first = r.json()
    assert first["saved"]["name"] == "L000" and first["count"] == 1
    print(f"\nsave: {1e3 * save_s:.1f} ms round trip ({first['save_ms']} ms in the server: execute + locked "
          "atomic write)")
    r = client.post("/api/sketches", json={"shape": "L", "waypoints": L_SECOND, "name": "dock_b"})
    assert r.status_code == 201, r.text
    listed = client.get("/api/sketches").json()["sketches"]
    assert [s["name"] for s in listed] == ["L000", "dock_b"]
    assert listed[0]["waypoints"] == L_WAYPOINTS and listed[0]["executed"]["deviation_m"] < 0.35
    assert client.get("/api/sketches/dock_b").json()["waypoints"] == L_SECOND

    loaded = load_sketch_file(out / "sketches.yaml")  # the format spade.annotate sketches= reads
    assert loaded.map == str(yaml_path.resolve())
    assert [(s.name, s.shape) for s in loaded.sketches] == [("L000", "L"), ("dock_b", "L")]
    np.testing.assert_allclose(loaded.sketches[1].waypoints_m, L_SECOND)

    assert client.delete("/api/sketches/L000").json()["count"] == 1
    assert client.delete("/api/sketches/L000").status_code == 404
    restarted = TestClient(build_app(str(yaml_path), out, TINY), base_url=LOCAL)  # a new server on the same out_dir
    assert [s["name"] for s in restarted.get("/api/sketches").json()["sketches"]] == ["dock_b"]
    r = restarted.post("/api/sketches", json={"shape": "L", "waypoints": L_WAYPOINTS})
    assert r.json()["saved"]["name"] == "L001"  # the first free default name after dock_b


def test_a_sketch_file_of_another_map_is_refused(setup, tmp_path: Path) -> None:
    client, _, out = setup
    client.post("/api/sketches", json={"shape": "L", "waypoints": L_WAYPOINTS})
    with pytest.raises(ValueError, match="holds sketches of map"):
        build_app("warehouse:1", out, TINY)


# ------------------------------------------------------------------------------------------------ bad requests
BAD = [
    ("POST", "/api/execute", b"{\"shape\": \"L\", \"waypoints\": [[0, 1], [1,", 400, "malformed JSON"),
    ("POST", "/api/sketches", b"not json", 400, "malformed JSON"),
    ("POST", "/api/execute", {"shape": "Z", "waypoints": L_WAYPOINTS}, 422, "unknown shape 'Z'"),
    ("POST", "/api/sketches", {"shape": "S", "waypoints": L_WAYPOINTS}, 422, "unknown shape 'S'"),
    ("POST", "/api/sketches", {"shape": "L", "waypoints": [[0.0, -3.0], [1.0, 1.0]]}, 422, "lies outside map"),
    ("POST", "/api/execute", {"shape": "L", "waypoints": [[0.0, 1.0]]}, 422, "at least 2"),
    ("POST", "/api/execute", {"shape": "L", "waypoints": [[0.0, 1.0, 2.0], [1.0, 1.0, 2.0]]}, 422,
     "at least 2 \\[x, y\\]"),
    ("POST", "/api/execute", {"shape": "L", "waypoints": "0,1 2,3"}, 422, "waypoints"),
    ("POST", "/api/execute", {"shape": "L"}, 422, "waypoints: missing"),
    ("POST", "/api/execute", {"shape": "L", "waypoints": L_WAYPOINTS, "speed": 3}, 422, "speed: unknown field"),
    ("POST", "/api/execute", b"{\"shape\": \"L\", \"waypoints\": [[0, 1], [NaN, 1]]}", 422, "finite|at least 2"),
    ("POST", "/api/execute", [1, 2], 422, "invalid request"),
    ("POST", "/api/sketches", {"shape": "U", "waypoints": [[0.0, 1.0], [4.0, 1.0]]}, 422,
     "not saved, the sketch is rejected \\(shape\\)"),
    ("POST", "/api/sketches", {"shape": "L", "waypoints": L_WAYPOINTS, "name": "../evil"}, 422, "not allowed"),
    ("POST", "/api/sketches", {"shape": "L", "waypoints": L_WAYPOINTS, "name": "L000"}, 409, "already saved"),
    ("DELETE", "/api/sketches/nope", None, 404, "no saved sketch named 'nope'"),
    ("GET", "/api/sketches/nope", None, 404, "no saved sketch named 'nope'"),
    ("POST", "/api/plan", {"pose": [0.0, 1.0, 0.0], "goal": [1.0, 1.0]}, 409, "no model loaded"),
    ("POST", "/api/model", {"path": "/nonexistent/student.ckpt"}, 404, "no such file"),
    ("GET", "/api/build/preview.png", None, 404, "build the dataset first"),
]


@pytest.mark.parametrize("method, url, body, status, message", BAD, ids=[f"{b[1]}:{b[4][:24]}" for b in BAD])
def test_bad_requests_get_a_4xx_with_a_message_and_leave_the_file_alone(setup, method, url, body, status,
                                                                          message) -> None:
    client, _, out = setup
    assert client.post("/api/sketches", json={"shape": "L", "waypoints": L_WAYPOINTS}).status_code == 201
    before = digest(out / "sketches.yaml")
    if isinstance(body, bytes):
        r = client.request(method, url, content=body, headers={"Content-Type": "application/json"})
    else:
        r = client.request(method, url, json=body)
    assert r.status_code == status, r.text
    assert re.search(message, r.json()["error"]), r.json()
    assert digest(out / "sketches.yaml") == before
    assert len(load_sketch_file(out / "sketches.yaml").sketches) == 1


def test_models_of_the_wrong_role_or_no_model_at_all_are_refused(setup, tmp_path: Path) -> None:
    client, _, _ = setup
    expert = student_checkpoint(tmp_path / "expert.ckpt", role="cond_expert")
    r = client.post("/api/model", json={"path": str(expert)})
    assert r.status_code == 422 and "'cond_expert'" in r.json()["error"], r.text  # says the role it found
    junk = tmp_path / "notes.ckpt"
    junk.write_text("not a checkpoint")
    r = client.post("/api/model", json={"path": str(junk)})
    assert r.status_code == 422 and "notes.ckpt" in r.json()["error"], r.text
    assert client.get("/api/model").json() == {"model": None}
    with pytest.raises(ValueError, match="cond_expert"):
        build_app(str(setup[1]), tmp_path / "other", TINY, model=expert)


# ------------------------------------------------------------------------------------------------ races
def test_concurrent_saves_from_two_servers_lose_nothing(setup) -> None:
    """Eight saves at once, half through a second server on the same sketch file: all land, the file stays valid."""
    client, yaml_path, out = setup
    other = TestClient(build_app(str(yaml_path), out, TINY), base_url=LOCAL)
    barrier = threading.Barrier(8)
    answers: list[int] = []

    def save(k: int) -> None:
        barrier.wait()
        r = (client if k % 2 else other).post("/api/sketches", json={"shape": "L", "waypoints": L_WAYPOINTS,
                                                                       "name": f"race_{k}"})
        answers.append(r.status_code)

    threads = [threading.Thread(target=save, args=(k,)) for k in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert answers == [201] * 8
    names = sorted(s.name for s in load_sketch_file(out / "sketches.yaml").sketches)
    assert names == [f"race_{k}" for k in range(8)]
    assert not list(out.glob(".sketches.yaml.*.tmp"))  # no temporary file left behind
    # default names never collide either
    threads = [threading.Thread(target=lambda: answers.append(
        client.post("/api/sketches", json={"shape": "L", "waypoints": L_WAYPOINTS}).status_code)) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert answers[8:] == [201] * 4
    assert len({s["name"] for s in client.get("/api/sketches").json()["sketches"]}) == 12


# ------------------------------------------------------------------------------------------------ dataset
def test_build_dataset_from_the_saved_sketches(setup) -> None:
    client, _, out = setup
    r = client.post("/api/build", json={})
    assert r.status_code == 409 and "no saved sketch" in r.json()["error"]
    for wp in (L_WAYPOINTS, L_SECOND):
        assert client.post("/api/sketches", json={"shape": "L", "waypoints": wp}).status_code == 201
    r = client.post("/api/build", json={"wait": True})
    assert r.status_code == 202, r.text
    job = client.get("/api/build").json()
    assert job["state"] == "done" and job["progress"] == 1.0, job
    assert job["summary"]["scenarios_accepted"] == 2 and job["summary"]["rejections"] == {}
    from spade.data.path_dataset import PathDataset

    ds = PathDataset(out / "dataset")
    assert len(ds) == job["instances"] > 20
    manifest = json.loads((out / "dataset" / "manifest.json").read_text())
    assert manifest["extra"]["source"] == "sketches"
    assert set(manifest["labels"]["scenario_id"]["values"]) == {"site/L000", "site/L001"}
    assert manifest["image_size"][0] == 64 and client.get("/api/build/preview.png").status_code == 200
    header = (out / "sketches.yaml").read_text().splitlines()[1]
    assert "python -m spade.annotate sketches=" in header and "window.size_px=64" in header


# ------------------------------------------------------------------------------------------------ the policy
def test_plan_with_a_student(setup, tmp_path: Path) -> None:
    from spade.maps import load_ros_map
    from spade.planner import Planner

    client, yaml_path, _ = setup
    ckpt = student_checkpoint(tmp_path / "student.ckpt")
    r = client.post("/api/model", json={"path": str(ckpt)})
    assert r.status_code == 200 and r.json()["model"]["image_size"] == [64, 64], r.text
    query = {"pose": [0.0, 1.0, 0.0], "goal": [2.0, 1.0]}
    r = client.post("/api/plan", json=query)  # untrained weights: the answer the planner gives for this file
    assert r.status_code == 200, r.text
    res = r.json()
    expected = Planner(ckpt).plan(load_ros_map(yaml_path), query["pose"], query["goal"])
    assert (res["success"], res["code"], res["reason"]) == (expected.success, expected.code, expected.reason)
    np.testing.assert_allclose(np.asarray(res["waypoints"]).reshape(-1, 2), expected.waypoints, atol=1e-4)
    assert res["probability"].startswith("data:image/png;base64,") and res["latency_ms"] > 0

    # A goal inside the site's block: no plan can reach it, a failure answer with its code, reason and picture.
    r = client.post("/api/plan", json={"pose": [2.5, 4.0, 0.0], "goal": BLOCK})
    assert r.status_code == 200, r.text
    res = r.json()
    assert res["success"] is False and res["code"] and res["reason"] and res["waypoints"] == [], res

    client.app.state.workspace.planner.backend = LineOracle()  # a network whose answer is known
    times = []
    for _ in range(5):
        t0 = time.perf_counter()
        res = client.post("/api/plan", json=query).json()
        times.append(1e3 * (time.perf_counter() - t0))
    assert res["success"], res
    wp = np.asarray(res["waypoints"])
    assert np.linalg.norm(wp[0] - query["pose"][:2]) < 0.3 and np.linalg.norm(wp[-1] - query["goal"]) < 0.3
    assert np.abs(wp[:, 1] - 1.0).max() < 0.3  # the straight line, in map metres
    baselines = {b["name"]: b for b in res["baselines"]}  # spade.metrics.baselines on the same window
    assert set(baselines) == {"straight", "shortest", "heading"} and baselines["straight"]["success"]
    np.testing.assert_allclose(baselines["straight"]["waypoints"][-1], query["goal"], atol=0.15)
    assert len(res["overlay"]["window_m"]) == 4
    print(f"\nplan: {np.median(times):.1f} ms round trip median of 5 ({res['latency_ms']} ms in the planner)")

    for body, message in (({"pose": [30.0, 1.0, 0.0], "goal": [1.0, 1.0]}, "robot pose .* lies outside the map"),
                          ({"pose": [0.0, 1.0], "goal": [1.0, 1.0]}, "pose \\(x, y, yaw\\) must be 3 finite"),
                          ({"pose": [0.0, 1.0, 0.0], "goal": [1.0, -9.0]}, "goal .* lies outside the map")):
        r = client.post("/api/plan", json=body)
        assert r.status_code == 422 and re.search(message, r.json()["error"]), r.text


class FaintLineOracle(LineOracle):
    """The line of :class:`LineOracle` over a background of p = 0.2 everywhere else, and a low-confidence flag."""

    def logits(self, states: np.ndarray) -> np.ndarray:
        out = super().logits(states)
        return np.where(out < 0, np.float32(np.log(0.2 / 0.8)), out).astype(np.float32)


def test_the_wash_covers_only_the_predicted_path_and_low_confidence_says_what_to_do(setup, tmp_path: Path) -> None:
    import base64
    import io

    from PIL import Image

    client, _, _ = setup
    assert client.post("/api/model", json={"path": str(student_checkpoint(tmp_path / "out" / "s.ckpt"))}).status_code == 200
    planner = client.app.state.workspace.planner
    planner.backend = FaintLineOracle()
    res = client.post("/api/plan", json={"pose": [0.0, 1.0, 0.0], "goal": [3.0, 1.0]}).json()
    assert res["success"], res
    overlay = res["overlay"]
    alpha = np.asarray(Image.open(io.BytesIO(base64.b64decode(overlay["png"].split(",", 1)[1]))))[..., 3]
    washed = alpha > 0
    assert overlay["threshold"] == planner.threshold and washed.any()
    # the washed cells: a band along the 3 m line (about 3 m / 0.1 m long), not the 64 x 64 window
    assert washed.sum() < 0.1 * 64 * 64, washed.sum()
    assert (res["confidence"] or {}).get("advice") is None  # a confident plan: nothing to do

    planner.low_confidence_share = -1.0  # every plan flagged: the page is told what to do
    res = client.post("/api/plan", json={"pose": [0.0, 1.0, 0.0], "goal": [3.0, 1.0]}).json()
    advice = res["confidence"]["advice"]
    assert res["confidence"]["low_confidence"] and advice.startswith("low confidence"), res["confidence"]
    assert "move the goal" in advice and "fallback=shortest" in advice and "sketch and save more" in advice


def test_sketch_file_written_by_the_app_is_plain_yaml(setup) -> None:
    client, _, out = setup
    client.post("/api/sketches", json={"shape": "L", "waypoints": L_WAYPOINTS, "name": "dock_a"})
    doc = yaml.safe_load((out / "sketches.yaml").read_text())
    assert doc["scenarios"][0]["name"] == "dock_a" and doc["scenarios"][0]["shape"] == "L"
