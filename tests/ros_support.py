"""Shared set-up for the ROS node tests: a loopback-only DDS domain, the node's output awaited, a student and its
export, a robot's recording, and the smallest Foxglove WebSocket client."""

from __future__ import annotations

import base64
import json
import os
import socket
import struct
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
MAP = ("turtlebot3", "turtlebot3_world.yaml")
POSE = (-0.55, 2.15, -0.015)  # a free, open stretch of turtlebot3_world (0.3 m clear along the way to the goal)
GOAL = (0.82, 1.545, 0.3)


LOOPBACK_XML = """<?xml version="1.0" encoding="UTF-8" ?>
<CycloneDDS><Domain Id="any">
  <General><Interfaces><NetworkInterface name="lo"/></Interfaces><AllowMulticast>false</AllowMulticast></General>
  <Discovery><ParticipantIndex>auto</ParticipantIndex><MaxAutoParticipantIndex>30</MaxAutoParticipantIndex>
    <Peers><Peer Address="127.0.0.1"/></Peers></Discovery>
</Domain></CycloneDDS>
"""


def student_files(folder: Path) -> tuple[Path, Path]:
    """An untrained small student as spade.train writes it (64 px robot-frame windows at 0.1 m/px) and its ONNX
    export (the search decoder makes an untrained network's plans valid paths all the same)."""
    import torch

    from spade.deploy.export import export_student
    from spade.maps.frame import RobotFrame
    from spade.models.builders import build_model

    torch.manual_seed(0)
    net = build_model("student", "small")
    info = {"role": "student", "config": dict(net.config),
            "data": {"image_size": [64, 64], "resolution_m": 0.1, "frame": RobotFrame.for_size(64).to_json()}}
    ckpt = folder / "student.ckpt"
    torch.save({"spade": info, "state_dict": {f"net.{k}": v for k, v in net.state_dict().items()}}, ckpt)
    return ckpt, export_student(ckpt, folder / "student.onnx", "onnx", latency_runs=0).out_path


def loopback_env(tmp_path: Path) -> dict[str, str]:
    """CYCLONEDDS_URI: loopback only, no multicast; SPADE_HOME in tmp_path (the node's run folder)."""
    xml = tmp_path / "cyclonedds.xml"
    xml.write_text(LOOPBACK_XML)
    return {**os.environ, "CYCLONEDDS_URI": xml.as_uri(), "SPADE_HOME": str(tmp_path / "home"),
            "PYTHONPATH": str(REPO), "HYDRA_FULL_ERROR": "0"}


def unique_domain() -> int:
    return 100 + os.getpid() % 100  # 100..199: away from ROS's default 0 and from other test runs' domains


def wait_for(log: Path, text: str, seconds: float) -> str:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        out = log.read_text(errors="replace")
        if text in out:
            return out
        time.sleep(0.1)
    raise AssertionError(f"{text!r} not in the node's output:\n{log.read_text(errors='replace')}")


class WsClient:
    """The smallest WebSocket client (RFC 6455) that Foxglove's protocol needs: text and binary frames."""

    def __init__(self, port: int, protocols: str = "foxglove.sdk.v1, foxglove.websocket.v1") -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=5)
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall((f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                           f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
                           f"Sec-WebSocket-Protocol: {protocols}\r\n\r\n").encode())
        head = b""
        while b"\r\n\r\n" not in head:
            head += self.sock.recv(1)
        self.head = head.decode(errors="replace")
        assert b" 101 " in head.split(b"\r\n")[0], head
        # the protocol the server chose, one of those offered (foxglove.sdk.v1: this SDK's own name)
        self.protocol = next(line.split(":", 1)[1].strip() for line in self.head.split("\r\n")
                             if line.lower().startswith("sec-websocket-protocol:"))
        assert self.protocol in protocols.split(", "), self.head

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


def advertised(client: WsClient, topics: set[str] | None = None, seconds: float = 5.0) -> dict[str, dict]:
    """The channels the server advertises (until ``topics`` are all there, or ``seconds`` pass), by topic."""
    channels: dict[str, dict] = {}
    client.sock.settimeout(0.5)
    end = time.monotonic() + seconds
    while time.monotonic() < end and (topics is None or not topics <= set(channels)):
        try:
            op, data = client.recv()
        except TimeoutError:
            if topics is None and channels:
                break
            continue
        if op == 1:
            msg = json.loads(data)
            if msg.get("op") == "advertise":
                channels.update({c["topic"]: c for c in msg["channels"]})
    client.sock.settimeout(5)
    return channels


def subscribe(client: WsClient, channels: dict[str, dict]) -> dict[int, str]:
    """Subscribe to every channel; returns subscription id -> topic."""
    subs = {i: topic for i, topic in enumerate(channels)}
    client.send_text(json.dumps({"op": "subscribe", "subscriptions": [
        {"id": i, "channelId": channels[topic]["id"]} for i, topic in subs.items()]}))
    return subs


def receive(client: WsClient, subs: dict[int, str], wanted: set[str], seconds: float) -> dict[str, list[bytes]]:
    """The messages received (payloads by topic) until every topic of ``wanted`` has one, or ``seconds`` pass."""
    got: dict[str, list[bytes]] = {}
    client.sock.settimeout(0.5)
    end = time.monotonic() + seconds
    while not wanted <= set(got) and time.monotonic() < end:
        try:
            op, data = client.recv()
        except TimeoutError:
            continue
        if op == 2 and data[0] == 0x01:
            got.setdefault(subs[struct.unpack("<I", data[1:5])[0]], []).append(data[13:])
    client.sock.settimeout(5)
    return got


def robot_bag(path: Path, frame: str = "map") -> Path:
    """A recording as a robot makes one: a latched map, AMCL poses at 10 Hz driving off the plan, two goals."""
    from spade.maps import generate_map
    from spade.ros.recording import BagMessages, BagWriter

    m = generate_map("warehouse", 2)
    t0 = 1_700_000_000_000_000_000
    with BagWriter(path) as bag:
        msgs = BagMessages(bag.typestore)
        T = bag.typestore.types
        bag.write("/map", "nav_msgs/msg/OccupancyGrid", msgs.grid(m, "map", t0), t0)

        def amcl(x: float, y: float, ns: int) -> object:
            cov = np.zeros(36)
            return T["geometry_msgs/msg/PoseWithCovarianceStamped"](
                msgs.header(frame, ns), T["geometry_msgs/msg/PoseWithCovariance"](msgs.pose(x, y, 0.0), cov))

        bag.write("/amcl_pose", "geometry_msgs/msg/PoseWithCovarianceStamped", amcl(2.0, 3.0, t0), t0)
        bag.write("/goal_pose", "geometry_msgs/msg/PoseStamped", msgs.pose_stamped([4.0, 3.0, 0.0], "map", t0 + 1),
                  t0 + 1)
        for i in range(1, 10):  # drifting sideways: 0.1 m per second, off the plan by > 0.5 m after 6 s
            ns = t0 + i * 1_000_000_000
            bag.write("/amcl_pose", "geometry_msgs/msg/PoseWithCovarianceStamped", amcl(2.0 + 0.1 * i, 3.0 + 0.1 * i,
                                                                                        ns), ns)
        bag.write("/goal_pose", "geometry_msgs/msg/PoseStamped", msgs.pose_stamped([99.0, 3.0, 0.0], "map", ns + 1),
                  ns + 1)
        bag.write("/scan_unrelated", "std_msgs/msg/Float32", msgs.float32(1.0), ns + 2)
    return path
