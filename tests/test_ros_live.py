"""Live Foxglove: a client speaking Foxglove's WebSocket protocol (foxglove.sdk.v1 / foxglove.websocket.v1, written here on a plain
socket) is advertised the node's channels and receives the map and a plan as ROS 2 CDR that decodes to what was
sent; the shipped layout file is well formed and names only channels SPADE serves (or records)."""

from __future__ import annotations

import base64
import json
import os
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

LAYOUT = Path(__file__).resolve().parents[1] / "docs" / "how-to" / "spade-foxglove-layout.json"


class WsClient:
    """The smallest WebSocket client (RFC 6455) that Foxglove's protocol needs: text and binary frames."""

    def __init__(self, port: int) -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=5)
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall((f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                           f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
                           "Sec-WebSocket-Protocol: foxglove.sdk.v1, foxglove.websocket.v1\r\n\r\n").encode())
        head = b""
        while b"\r\n\r\n" not in head:
            head += self.sock.recv(1)
        assert b" 101 " in head.split(b"\r\n")[0], head
        assert b"foxglove." in head  # foxglove.sdk.v1 (this SDK) or foxglove.websocket.v1

    def _read(self, n: int) -> bytes:
        out = b""
        while len(out) < n:
            chunk = self.sock.recv(n - len(out))
            if not chunk:
                raise ConnectionError("closed")
            out += chunk
        return out

    def recv(self) -> tuple[int, bytes]:
        b0, b1 = self._read(2)
        n = b1 & 0x7F
        if n == 126:
            n = struct.unpack(">H", self._read(2))[0]
        elif n == 127:
            n = struct.unpack(">Q", self._read(8))[0]
        return b0 & 0x0F, self._read(n)

    def send_text(self, text: str) -> None:
        data = text.encode()
        mask = os.urandom(4)
        head = bytes([0x81]) + (bytes([0x80 | len(data)]) if len(data) < 126 else
                                bytes([0x80 | 126]) + struct.pack(">H", len(data)))
        self.sock.sendall(head + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(data)))


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
    from spade.deploy.student_planner import PlanWindow
    from spade.maps import FREE, OCCUPIED, OccupancyMap
    from spade.maps.frame import RobotFrame
    from spade.ros.live import window_grids

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
    from spade.deploy.student_planner import PlanWindow
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
