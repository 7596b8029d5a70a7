"""The sketching page in a real browser: ``python -m spade.sketch`` started on a free port on a real ROS map,
Playwright driving Debian's chromium (tests/browser_support.py) through map, sketch, execute, save, the saved
list, dataset build, two tabs saving at once and "Try the policy"; screenshots of each step go to test-artifacts/.
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from browser_support import browser_page, screenshot
from spade.annotation.sketch_file import load_sketch_file

pytestmark = pytest.mark.slow  # a spade.sketch server and a browser; the API in-process: test_sketch_api.py

ROOT = Path(__file__).resolve().parents[1]
MAP = "aws-robomaker-small-warehouse-world/small_warehouse_005.yaml"
# L sketches on that map (map-frame metres), accepted by the annotation tool's execution with 64 px x 0.1 m windows.
L_MAIN = [[-3.0, -5.0], [-3.0, -4.0], [-3.0, -3.0], [-2.85, -2.45], [-2.45, -2.1], [-2.0, -2.0], [-1.2, -2.0]]
L_TAB_A = [[0.0, -6.0], [0.0, -5.0], [0.0, -4.0], [-0.15, -3.45], [-0.55, -3.1], [-1.0, -3.0], [-1.8, -3.0]]
L_TAB_B = [[-6.0, -5.0], [-6.0, -3.0], [-4.0, -3.0]]
# An L whose goal lies 3 m to the right of its start: outside the 6.4 m window's margin (waypoint #7).
L_WIDE = [[-3.0, -5.5], [-3.0, -4.0], [-3.0, -3.0], [-2.85, -2.45], [-2.45, -2.1], [-2.0, -2.0], [0.0, -2.0]]
SHIFT_M = np.array([0.02, -0.02]) / np.sqrt(2.0)  # 2 cm


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def student_checkpoint(path: Path) -> Path:
    """An untrained small student as spade.train writes it (robot frame, 64 px at 0.1 m)."""
    import torch

    from spade.maps.frame import RobotFrame
    from spade.models.builders import build_model

    net = build_model("student", "small")
    info = {"role": "student", "config": dict(net.config),
            "data": {"image_size": [64, 64], "resolution_m": 0.1, "frame": RobotFrame.for_size(64).to_json()}}
    torch.save({"spade": info, "state_dict": {f"net.{k}": v for k, v in net.state_dict().items()}}, path)
    return path


@pytest.fixture
def server(maps_dir: Path, tmp_path: Path) -> Iterator[tuple[str, Path]]:
    """``python -m spade.sketch MAP port=... out_dir=... model=...`` on 127.0.0.1: (base url, out_dir)."""
    port, out = free_port(), tmp_path / "sketches"
    # SPADE_SKETCH_TEST_MODEL: a trained student (64 px x 0.1 m, e.g. scale=tiny) for the README's pictures
    model = tmp_path / "student.ckpt"  # in the server's folder: the page shows paths relative to it
    if os.environ.get("SPADE_SKETCH_TEST_MODEL"):
        shutil.copyfile(os.environ["SPADE_SKETCH_TEST_MODEL"], model)
    else:
        student_checkpoint(model)
    cmd = [sys.executable, "-m", "spade.sketch", str(maps_dir / MAP), f"port={port}", f"out_dir={out}",
           f"model={model}", "annotate.window.size_px=64",
           "annotate.window.resolution_m=0.1", "annotate.instances.spacing_m=0.1", "annotate.preview.count=8",
           f"hydra.run.dir={tmp_path / 'hydra'}"]
    log = open(tmp_path / "server.log", "w")
    proc = subprocess.Popen(cmd, cwd=tmp_path, stdout=log, stderr=subprocess.STDOUT, env={**os.environ})
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 150  # a loaded 2-core machine takes ~35 s (torch, hydra, costmap)
        while True:
            try:
                with urllib.request.urlopen(f"{url}/api/map", timeout=2) as r:
                    assert json.load(r)["map_id"] == "small_warehouse_005"
                    break
            except OSError:
                if proc.poll() is not None or time.monotonic() > deadline:
                    pytest.fail(f"spade.sketch did not start: {(tmp_path / 'server.log').read_text()[-3000:]}")
                time.sleep(0.25)
        yield url, out
    finally:
        proc.terminate()
        proc.wait(timeout=20)
        log.close()


def click_world(page, points: list[list[float]]) -> None:
    """Click map-frame points on the canvas, like an operator."""
    box = page.locator("#canvas").bounding_box()
    for x, y in points:
        sx, sy = page.evaluate("([x, y]) => window.spade.worldToScreen(x, y)", [x, y])
        page.mouse.click(box["x"] + sx, box["y"] + sy)


def screen(page, x: float, y: float) -> tuple[float, float]:
    box = page.locator("#canvas").bounding_box()
    sx, sy = page.evaluate("([x, y]) => window.spade.worldToScreen(x, y)", [x, y])
    return box["x"] + sx, box["y"] + sy


def zoom_to(page, x: float, y: float, notches: int) -> None:
    """Wheel-zoom about a map point; the point must stay under the cursor."""
    sx, sy = screen(page, x, y)
    page.mouse.move(sx, sy)
    for _ in range(notches):
        page.mouse.wheel(0, -120)
    page.wait_for_timeout(50)
    after = screen(page, x, y)
    assert abs(after[0] - sx) < 1.0 and abs(after[1] - sy) < 1.0


def saved_names(out: Path) -> list[str]:
    return [s.name for s in load_sketch_file(out / "sketches.yaml").sketches]


def test_sketch_execute_save_build_and_plan_in_the_browser(server: tuple[str, Path]) -> None:
    url, out = server
    timings: dict[str, float] = {}
    with browser_page(1400, 1000) as page:
        page.goto(url)
        page.wait_for_selector("body[data-ready='1']", timeout=30_000)
        assert "small_warehouse_005" in page.inner_text("#map-info")
        scale0 = page.evaluate("window.spade.state.view.scale")
        zoom_to(page, -2.5, -3.5, 5)
        assert page.evaluate("window.spade.state.view.scale") > 1.5 * scale0
        # pan: drag the map; the sketch stays empty
        sx, sy = screen(page, 2.0, 2.0)
        page.mouse.move(sx, sy)
        page.mouse.down()
        page.mouse.move(sx + 40, sy - 30, steps=4)
        page.mouse.up()
        assert page.evaluate("window.spade.state.waypoints.length") == 0
        page.check("#costmap-toggle")
        screenshot(page, "sketch_1_map.png")

        # sketch: one point misplaced then moved, one extra point undone
        click_world(page, [L_MAIN[0], [-3.6, -4.0], *L_MAIN[2:], [1.0, 1.0]])
        assert page.inner_text("#waypoint-count") == "8 waypoints"
        page.click("#undo")
        assert page.inner_text("#waypoint-count") == "7 waypoints"
        a, b = screen(page, -3.6, -4.0), screen(page, *L_MAIN[1])
        page.mouse.move(*a)
        page.mouse.down()
        page.mouse.move(*b, steps=5)
        page.mouse.up()
        drawn = np.asarray(page.evaluate("window.spade.state.waypoints"))
        res = page.evaluate("window.spade.state.meta.resolution") / page.evaluate("window.spade.state.view.scale")
        assert np.abs(drawn - np.asarray(L_MAIN)).max() < 2 * res  # within two screen pixels
        # the student's window is drawn while sketching, before any execution, with the fit's verdict
        before = page.evaluate("window.spade.state.window")
        assert before and page.get_attribute("#window-fit", "data-fits") == "1", page.inner_text("#window-fit")
        assert "Fits the student's window" in page.inner_text("#window-fit")
        assert page.inner_text("#fit") == "Fit"  # the view's button keeps its label
        page.click("#execute")
        page.wait_for_selector("#result.accepted")
        assert "Accepted" in page.inner_text("#result") and page.is_enabled("#save")
        served = page.evaluate("window.spade.state.execution.window.corners_m")
        np.testing.assert_allclose(before["corners"], served, atol=0.01)  # the page draws the window checked
        screenshot(page, "sketch_2_executed.png")

        t0 = time.perf_counter()
        page.click("#save")
        page.wait_for_selector("#saved tr[data-name='L000']")
        timings["save (click to listed)"] = time.perf_counter() - t0
        assert "Saved as L000" in page.inner_text("#result")
        saved = load_sketch_file(out / "sketches.yaml")
        assert [(s.name, s.shape) for s in saved.sketches] == [("L000", "L")]
        np.testing.assert_allclose(saved.sketches[0].waypoints_m, drawn, atol=1e-3)
        screenshot(page, "sketch_3_saved.png")

        # a sketch outside the window: seen before executing, the waypoint named; shifted by 2 cm, the same verdict
        page.click("#clear")
        verdicts = []
        for shift in (np.zeros(2), SHIFT_M, -SHIFT_M):
            page.click("#clear")
            click_world(page, (np.asarray(L_WIDE) + shift).tolist())
            assert page.get_attribute("#window-fit", "data-fits") == "0", page.inner_text("#window-fit")
            assert json.loads(page.get_attribute("#window-fit", "data-outside")) == [6], page.inner_text("#window-fit")
            assert "#7 outside the student's window" in page.inner_text("#window-fit")
            if not verdicts:
                screenshot(page, "sketch_2b_window_before_execute.png")
            page.click("#execute")
            page.wait_for_selector("#result.rejected")
            result = page.evaluate("window.spade.state.execution")
            verdicts.append((result["reason"], result["offending_waypoints"]))
            assert "waypoint #7" in page.inner_text("#result") and "#6" not in page.inner_text("#result")
        assert verdicts == [("window", [6])] * 3, verdicts
        screenshot(page, "sketch_2c_window_rejected.png")
        for shift in (SHIFT_M, -SHIFT_M):  # the accepted L, shifted by 2 cm: accepted too
            page.click("#clear")
            click_world(page, (np.asarray(L_MAIN) + shift).tolist())
            assert page.get_attribute("#window-fit", "data-fits") == "1"
            page.click("#execute")
            page.wait_for_selector("#result.accepted, #result.rejected")
            assert "Accepted" in page.inner_text("#result"), page.inner_text("#result")
        page.click("#clear")

        # a rejected sketch: a straight drive labelled U, the reason in words
        page.check("input[name=shape][value=U]")
        click_world(page, [[-4.5, -4.5], [-4.5, -2.5]])
        page.click("#execute")
        page.wait_for_selector("#result.rejected")
        assert "does not turn like the shape" in page.inner_text("#result") and page.is_disabled("#save")
        screenshot(page, "sketch_4_rejected.png")
        page.click("#clear")
        page.check("input[name=shape][value=L]")
        # freehand: Alt+drag leaves a waypoint every 0.3 m; one undo removes the stroke
        a, b = screen(page, -4.5, -4.5), screen(page, -4.5, -2.5)
        page.keyboard.down("Alt")
        page.mouse.move(*a)
        page.mouse.down()
        page.mouse.move(*b, steps=20)
        page.mouse.up()
        page.keyboard.up("Alt")
        assert page.evaluate("window.spade.state.waypoints.length") >= 6
        page.click("#undo")
        assert page.inner_text("#waypoint-count") == "0 waypoints"

        # two tabs save at the same moment: both land
        tab = page.context.browser.new_page(viewport={"width": 1400, "height": 1000})
        tab.goto(url)
        tab.wait_for_selector("body[data-ready='1']")
        for p, sketch in ((page, L_TAB_A), (tab, L_TAB_B)):
            click_world(p, sketch)
            p.click("#execute")
            p.wait_for_selector("#result.accepted")
        page.evaluate("document.getElementById('save').click()")  # returns at once; the request is in flight
        tab.evaluate("document.getElementById('save').click()")
        for p in (page, tab):
            p.wait_for_function("document.getElementById('result').textContent.startsWith('Saved as')")
        assert sorted(saved_names(out)) == ["L000", "L001", "L002"]
        for p in (page, tab):  # each tab's list catches up with the other's save (it polls the server)
            p.wait_for_function("document.querySelectorAll('#saved tr').length === 3", timeout=10_000)
        tab.close()

        # review and delete in the list
        page.on("dialog", lambda dialog: dialog.accept())
        page.click("#saved tr[data-name='L002'] button.show")
        page.click("#saved tr[data-name='L002'] button.delete")
        page.wait_for_function("document.querySelectorAll('#saved tr').length === 2")
        assert saved_names(out) == ["L000", "L001"]

        # build the dataset
        page.click("#build")
        page.wait_for_selector("#build-status[data-state='done']", timeout=60_000)
        page.wait_for_selector("#build-preview:not([hidden])")
        status = page.inner_text("#build-status")
        assert "from 2 of 2 sketches" in status, status
        screenshot(page, "sketch_5_dataset.png")
        from spade.data.path_dataset import PathDataset

        ds = PathDataset(out / "dataset")
        manifest = json.loads((out / "dataset" / "manifest.json").read_text())
        assert len(ds) > 20 and manifest["extra"]["source"] == "sketches"
        assert set(manifest["labels"]["scenario_id"]["values"]) == {"small_warehouse_005/L000",
                                                                    "small_warehouse_005/L001"}
        assert f"{len(ds)} instances" in status

        # try the policy: press at the robot, drag along its heading (+y), click the goal
        page.check("#mode-policy")
        rx, ry = screen(page, -3.0, -5.0)
        page.mouse.move(rx, ry)
        page.mouse.down()
        page.mouse.move(rx, ry - 40, steps=4)
        page.mouse.up()
        click_world(page, [[-2.0, -3.5]])
        pose = page.evaluate("window.spade.state.pose")
        assert np.allclose(pose[:2], [-3.0, -5.0], atol=0.1) and abs(pose[2] - np.pi / 2) < 0.05
        t0 = time.perf_counter()
        page.click("#plan")
        page.wait_for_selector("#plan-result.success, #plan-result.failure")
        timings["plan (click to shown)"] = time.perf_counter() - t0
        assert page.is_visible("#plan-probability")  # an untrained student: the answer may be "no path", with why
        text = page.inner_text("#plan-result")
        assert "ms" in text and ("Path of" in text or "No path (" in text), text
        assert "baseline shortest" in page.inner_text("#baselines")
        screenshot(page, "sketch_6_policy.png")
    print("\n" + ", ".join(f"{k}: {1e3 * v:.0f} ms" for k, v in timings.items()))


def test_the_page_and_the_server_give_one_fit_verdict_at_the_margin(server: tuple[str, Path], tmp_path: Path) -> None:
    """An L whose goal lies 1 cm inside (outside) the window's margin, shifted by up to 2 cm: the page's live verdict
    (computed from the rule's numbers the server serves) is the same for every shift and equals the server's check
    on Execute; the page then shows the server's verdict. Execute waits for 2 waypoints."""
    url, _ = server
    with browser_page(1600, 1000) as page:
        page.goto(url)
        page.wait_for_selector("body[data-ready='1']", timeout=30_000)
        assert page.is_disabled("#execute")  # no waypoints yet
        click_world(page, [L_MAIN[0]])
        assert page.is_disabled("#execute") and "1 more waypoint" in page.get_attribute("#execute", "title")
        rule = page.evaluate("window.spade.state.meta.window")
        # L_MAIN heads +y from its start and turns right: the window's right margin lies this far to its right
        lateral = (rule["size_px"] - 1 - rule["robot_px"][0] - rule["margin_m"] / rule["resolution_m"]) \
            * rule["resolution_m"]
        for slack in (0.01, -0.01):
            sketch = np.asarray(L_MAIN)
            sketch[-1, 0] = sketch[0, 0] + lateral - slack
            verdicts = set()
            for k, shift in enumerate((np.zeros(2), SHIFT_M, -SHIFT_M, SHIFT_M[::-1], -SHIFT_M[::-1])):
                page.evaluate("(p) => window.spade.setSketch(p)", (sketch + shift).tolist())
                assert page.is_enabled("#execute")
                live = page.get_attribute("#window-fit", "data-fits")
                assert page.get_attribute("#window-fit", "data-source") == "page"
                page.click("#execute")
                page.wait_for_selector("#result.accepted, #result.rejected")
                served = page.evaluate("window.spade.state.execution.window")
                assert live == ("1" if served["fits"] else "0"), (slack, shift, page.inner_text("#window-fit"))
                assert page.get_attribute("#window-fit", "data-fits") == live  # the server's verdict, shown
                assert page.get_attribute("#window-fit", "data-source") == "server"
                verdicts.add((live, page.get_attribute("#result", "class"), json.dumps(served["outside_waypoints"])))
                if k == 0:
                    shot = tmp_path / f"fit_at_margin_{'inside' if slack > 0 else 'outside'}.png"
                    page.screenshot(path=str(shot), full_page=True)
                    screenshot(page, shot.name)
            expected = ("1", "result accepted", "[]") if slack > 0 else ("0", "result rejected", "[6]")
            assert verdicts == {expected}, (slack, verdicts)
        page.click("#clear")
        assert page.is_disabled("#execute")
