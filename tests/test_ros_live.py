"""Live Foxglove: a client speaking Foxglove's WebSocket protocol (foxglove.sdk.v1 / foxglove.websocket.v1, written
here on a plain socket) is advertised the node's channels and receives the map and a plan as ROS 2 CDR that decodes
to what was sent; a viewer that connects late still gets the map, the goal and the last plan (latched channels),
under either protocol name, and a client offering neither is told why, once; the simulator's server advertises only
what it carries; the shipped layout file is well formed, names only channels SPADE serves (or records), lies in the
package and is linked from the documentation."""

from __future__ import annotations

import json
import socket
import struct
import time
from pathlib import Path
from types import SimpleNamespace as NS

import numpy as np
import pytest

pytest.importorskip("foxglove")
pytest.importorskip("cyclonedds")

from spade.ros import messages as M  # noqa: E402
from spade.ros.live import CHANNELS, FoxgloveLive  # noqa: E402
from ros_support import WsClient, advertised, receive, subscribe

REPO = Path(__file__).resolve().parents[1]
LAYOUT = REPO / "docs" / "how-to" / "spade-foxglove-layout.json"


def test_a_foxglove_client_receives_the_map_and_a_plan() -> None:
    from spade.maps import FREE, OccupancyMap

    live = FoxgloveLive("127.0.0.1", 0)
    try:
        client = WsClient(live.port)
        channels: dict[str, dict] = {}
        end = time.monotonic() + 5
        while len(channels) < len(CHANNELS) and time.monotonic() < end:
            op, data = client.recv()
            if op == 1:
                msg = json.loads(data)
                if msg.get("op") == "advertise":
                    channels.update({c["topic"]: c for c in msg["channels"]})
        assert set(channels) == {topic for topic, _ in CHANNELS.values()}
        assert channels["/map"]["schemaName"] == "nav_msgs/msg/OccupancyGrid" and channels["/map"]["encoding"] == "cdr"
        assert channels["/tf"]["schemaName"] == "tf2_msgs/msg/TFMessage"
        ids = {c["id"]: topic for topic, c in channels.items()}
        client.send_text(json.dumps({"op": "subscribe", "subscriptions": [
            {"id": i, "channelId": cid} for i, cid in enumerate(ids)]}))
        time.sleep(0.3)
        m = OccupancyMap(np.full((40, 60), FREE, np.uint8), 0.1, (1.0, 2.0, 0.0), name="m")
        live.on_message("map", M.occupancy_grid(m, "map"))
        live.on_message("pose", M.pose_with_covariance((2.0, 3.0, 0.5), "map"))
        path = M.path(np.array([[2.0, 3.0], [3.0, 3.5]]), "map", 10**9, 0.0)
        live.on_plan(NS(result=NS(window=None), stamp_ns=10**9, frame_id="map"), path)
        got: dict[str, bytes] = {}
        end = time.monotonic() + 5
        subscription_topic = {i: ids[cid] for i, cid in enumerate(ids)}
        while not {"/map", "/plan", "/tf", "/amcl_pose"} <= set(got) and time.monotonic() < end:
            op, data = client.recv()
            if op == 2 and data[0] == 0x01:  # messageData: opcode, subscription id, timestamp, payload
                sub = struct.unpack("<I", data[1:5])[0]
                got[subscription_topic[sub]] = data[13:]
        grid = M.OccupancyGrid.deserialize(got["/map"])
        assert (grid.info.width, grid.info.height) == (60, 40) and grid.info.origin.position.x == pytest.approx(1.0)
        plan = M.Path.deserialize(got["/plan"])
        assert [p.pose.position.x for p in plan.poses] == [2.0, 3.0]
        tf = M.TFMessage.deserialize(got["/tf"]).transforms[0]
        assert (tf.header.frame_id, tf.child_frame_id) == ("map", "base_link")
        assert tf.transform.translation.x == pytest.approx(2.0)
    finally:
        live.close()


def test_the_plan_window_and_probabilities_are_grids_in_the_window_frame() -> None:
    from spade.deploy.robot_window import PlanWindow
    from spade.maps import FREE, OCCUPIED, OccupancyMap
    from spade.maps.frame import RobotFrame
    from spade.ros.window_messages import window_grids

    grid = np.full((100, 100), FREE, np.uint8)
    grid[10, 50] = OCCUPIED
    m = OccupancyMap(grid, 0.1, (0.0, 0.0, 0.0))
    frame = RobotFrame.for_size(16)
    window = PlanWindow(m, frame.place(np.array([50.0, 50.0]), 0.0))
    prob = np.zeros((16, 16))
    prob[4, 8] = 0.9  # 0.4 m ahead of the robot (robot at row 12, column 8)
    occ, probability = window_grids(NS(window=window, probability=prob), 5)
    assert occ.header.frame_id == probability.header.frame_id == "spade_window"
    assert (occ.info.width, occ.info.height) == (16, 16)
    data = np.array(probability.data).reshape(16, 16)  # row 0 at the origin (behind-right of the robot)
    j, i = np.argwhere(data == 90)[0]
    x = probability.info.origin.position.x + (i + 0.5) * 0.1
    y = probability.info.origin.position.y + (j + 0.5) * 0.1
    assert x == pytest.approx(0.8, abs=0.06) and y == pytest.approx(0.0, abs=0.06)


def test_the_shipped_layout_is_a_foxglove_layout_of_spades_channels() -> None:
    layout = json.loads(LAYOUT.read_text())
    assert {"configById", "layout", "globalVariables", "userNodes"} <= set(layout)

    def panels(node) -> list[str]:  # noqa: ANN001
        if isinstance(node, str):
            return [node]
        assert node["direction"] in ("row", "column") and 0 < node.get("splitPercentage", 50) < 100
        return panels(node["first"]) + panels(node["second"])

    used = panels(layout["layout"])
    assert sorted(used) == sorted(layout["configById"])
    for pid in used:
        assert pid.split("!")[0] in ("3D", "Plot", "RawMessages"), pid
    served = {topic for topic, _ in CHANNELS.values()} | {"/plan_confidence"}  # the node's confidence topic
    assert set(layout["configById"]["3D!spade"]["topics"]) <= served
    assert layout["configById"]["RawMessages!plan"]["topicPath"] in served


def test_recordings_carry_tf_and_the_students_window(tmp_path: Path) -> None:
    mcap_ros2 = pytest.importorskip("mcap_ros2.reader")
    from spade.deploy.robot_window import PlanWindow
    from spade.maps import FREE, OccupancyMap
    from spade.maps.frame import RobotFrame
    from spade.ros.node import Topics
    from spade.ros.recording import NodeRecorder

    m = OccupancyMap(np.full((100, 100), FREE, np.uint8), 0.1, (0.0, 0.0, 0.0))
    window = PlanWindow(m, RobotFrame.for_size(16).place(np.array([50.0, 50.0]), 0.0))
    recorder = NodeRecorder(tmp_path / "s.mcap", Topics())
    recorder.message("pose", M.pose_with_covariance((5.0, 5.0, 0.0), "map", 10**9), 10**9)
    result = NS(window=window, probability=np.full((16, 16), 0.5), pose=np.array([5.0, 5.0, 0.0]))
    recorder.plan(NS(result=result, stamp_ns=2 * 10**9, frame_id="map"), None)
    recorder.close()
    got = [(r.channel.topic, r.ros_msg) for r in mcap_ros2.read_ros2_messages(str(tmp_path / "s.mcap"))]
    topics = [t for t, _ in got]
    assert topics.count("/tf") == 2 and "/plan_window" in topics and "/plan_probability" in topics
    children = {msg.transforms[0].child_frame_id for t, msg in got if t == "/tf"}
    assert children == {"base_link", "spade_window"}
    assert set(dict(got)["/plan_probability"].data) == {50}


@pytest.mark.parametrize("protocols", ["foxglove.websocket.v1", "foxglove.sdk.v1"])
def test_a_viewer_that_connects_after_the_map_gets_the_map_the_goal_and_the_last_plan(protocols: str) -> None:
    """Every channel is latched as a transient-local ROS topic is: the map, the goal, the last plan and the robot's
    transform, all sent before the viewer connected, reach it when it subscribes; under the old protocol name too."""
    from spade.maps import FREE, OccupancyMap

    live = FoxgloveLive("127.0.0.1", 0)
    try:
        m = OccupancyMap(np.full((40, 60), FREE, np.uint8), 0.1, (1.0, 2.0, 0.0), name="m")
        live.on_message("map", M.occupancy_grid(m, "map"))
        live.on_message("goal", M.pose_stamped((3.0, 3.5, 0.5), "map"))
        live.on_message("pose", M.pose_with_covariance((2.0, 3.0, 0.5), "map"))
        for x in (2.5, 3.0):  # two plans: the viewer gets the last one
            live.on_plan(NS(result=NS(window=None), stamp_ns=10**9, frame_id="map", confidence=0.75),
                         M.path(np.array([[2.0, 3.0], [x, 3.5]]), "map", 10**9, 0.0))
        client = WsClient(live.port, protocols)
        assert client.protocol == protocols  # the old name is answered with the old name
        channels = advertised(client, {topic for topic, _ in CHANNELS.values()})
        subs = subscribe(client, channels)
        wanted = {"/map", "/goal_pose", "/plan", "/plan_confidence", "/amcl_pose", "/tf"}
        got = receive(client, subs, wanted, 5)
        assert wanted <= set(got), sorted(got)
        grid = M.OccupancyGrid.deserialize(got["/map"][0])
        assert (grid.info.width, grid.info.height) == (60, 40)
        goal = M.PoseStamped.deserialize(got["/goal_pose"][0])
        assert (goal.pose.position.x, goal.pose.position.y) == (3.0, 3.5)
        plans = [M.Path.deserialize(b) for b in got["/plan"]]
        assert len(plans) == 1 and plans[0].poses[-1].pose.position.x == 3.0  # the last plan only (depth 1)
        assert M.Float32.deserialize(got["/plan_confidence"][0]).data == pytest.approx(0.75)
        # a second late viewer gets them too; a new map replaces the latched one
        live.on_message("map", M.occupancy_grid(OccupancyMap(np.full((10, 20), FREE, np.uint8), 0.1,
                                                             (0.0, 0.0, 0.0)), "map"))
        second = WsClient(live.port)
        got2 = receive(second, subscribe(second, advertised(second, {"/map", "/goal_pose"})), {"/map", "/goal_pose"},
                       5)
        assert M.OccupancyGrid.deserialize(got2["/map"][-1]).info.width == 20
    finally:
        live.close()


def test_a_client_offering_neither_protocol_name_is_told_why_and_it_is_logged_once(
        caplog: pytest.LogCaptureFixture) -> None:
    live = FoxgloveLive("127.0.0.1", 0)
    try:
        replies = []
        with caplog.at_level("DEBUG", logger="spade.ros"):
            for _ in range(3):  # a viewer retries about once a second
                sock = socket.create_connection(("127.0.0.1", live.port), timeout=5)
                sock.sendall(b"GET / HTTP/1.1\r\nHost: x\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                             b"Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n"
                             b"Sec-WebSocket-Protocol: rosbridge.v2\r\n\r\n")
                reply = b""
                while chunk := sock.recv(4096):
                    reply += chunk
                sock.close()
                replies.append(reply.decode())
        assert all(r.startswith("HTTP/1.1 400") for r in replies)
        assert "foxglove.sdk.v1, foxglove.websocket.v1" in replies[0] and "rosbridge.v2" in replies[0]
        warnings = [r for r in caplog.records if r.levelname == "WARNING" and "refused" in r.getMessage()]
        assert len(warnings) == 1 and "said once" in warnings[0].getMessage()
        client = WsClient(live.port)  # a good client still connects
        assert client.protocol == "foxglove.sdk.v1"
    finally:
        live.close()


def test_the_simulators_server_advertises_only_what_it_carries() -> None:
    """The desk simulator has no window, probabilities or confidence (the node's): its server does not offer them."""
    from spade.ros.live import SIM_CHANNELS

    assert set(SIM_CHANNELS) == {"map", "pose", "goal", "plan", "tf"}
    live = FoxgloveLive("127.0.0.1", 0, channels=SIM_CHANNELS)
    try:
        channels = advertised(WsClient(live.port), seconds=2)
        assert set(channels) == {CHANNELS[k][0] for k in SIM_CHANNELS}
        live.on_plan(None, M.path(np.array([[0.0, 0.0], [1.0, 0.0]]), "map", 10**9))  # the sim's plans: no event
    finally:
        live.close()
    with pytest.raises(ValueError, match="not among"):
        FoxgloveLive("127.0.0.1", 0, channels=["costmap"])


def test_a_port_in_use_is_one_line_naming_the_option() -> None:
    from spade.utils.errors import ConfigError

    holder = socket.create_server(("127.0.0.1", 0))
    try:
        with pytest.raises(ConfigError, match=r"^foxglove_port=\d+: cannot listen .* choose another foxglove_port"):
            FoxgloveLive("127.0.0.1", holder.getsockname()[1])
    finally:
        holder.close()


def test_the_layout_ships_in_the_package_and_the_site_links_it() -> None:
    from spade.ros.live import LAYOUT as PACKAGED

    assert PACKAGED.is_file() and PACKAGED.parent == REPO / "spade" / "ros"
    assert LAYOUT.resolve() == PACKAGED.resolve()  # the site's copy is the package's file
    pyproject = (REPO / "pyproject.toml").read_text()
    assert '"spade.ros" = ["foxglove_layout.json"]' in pyproject
    page = (REPO / "docs" / "deployment.md").read_text()
    assert "](how-to/spade-foxglove-layout.json)" in page  # a link, downloadable from the site
