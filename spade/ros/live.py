"""Live Foxglove: ``foxglove=true`` on the node and the desk simulator serves what they see over Foxglove's
WebSocket protocol (``foxglove-sdk``; Foxglove's "Open connection" -> Foxglove WebSocket -> ``ws://HOST:PORT``).

Every channel carries ROS 2 messages as ROS 2 serialises them (CDR, schema ``ros2msg``), so Foxglove's panels show
them as they show a robot's topics, and the shipped layout (:data:`LAYOUT`, ``spade/ros/foxglove_layout.json``,
also on the documentation site) opens the same on a live node, a recording or a robot:

======================  ================================  ======================================================
``/map``                ``nav_msgs/msg/OccupancyGrid``    the map the node plans on
``/amcl_pose``          ``PoseWithCovarianceStamped``     the robot's pose
``/goal_pose``          ``geometry_msgs/msg/PoseStamped`` goals (topic goals and ``ComputePathToPose`` goals)
``/plan``               ``nav_msgs/msg/Path``             every plan published
``/plan_confidence``    ``std_msgs/msg/Float32``          each plan's confidence (1 - its low-probability share)
``/plan_window``        ``nav_msgs/msg/OccupancyGrid``    the student's window of the last plan (frame ``spade_window``)
``/plan_probability``   ``nav_msgs/msg/OccupancyGrid``    its path probabilities (0..100) in the same frame
``/tf``                 ``tf2_msgs/msg/TFMessage``        ``map -> base_link`` (the robot) and ``map -> spade_window``
======================  ================================  ======================================================

A server advertises only the channels it carries (the simulator's: :data:`SIM_CHANNELS`, no window, probabilities
or confidence: those are the node's). Every channel is latched as a ROS 2 transient-local topic of depth 1 is: its
last message (on ``/tf`` the last transform of each child frame) is sent again to each new subscriber, so a viewer
that connects after the map was published still gets the map, the goal and the last plan. (The SDK sends that copy
to every subscriber of the channel: a viewer already connected gets the same message once more.)

The SDK's server speaks ``foxglove.sdk.v1``; older viewers (Lichtblick, Foxglove before 2025, foxglove_bridge's
clients) ask for ``foxglove.websocket.v1``, the same protocol under its old name. :class:`ProtocolFront` listens on
the port and takes both names; a client that offers neither gets HTTP 400 with the reason, logged once.
"""

from __future__ import annotations

import contextlib
import logging
import socket
import threading
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from spade.ros import messages as M
from spade.ros.convert import quaternion_to_yaw
from spade.ros.window_messages import WINDOW_FRAME, window_grids
from spade.utils.errors import ConfigError

__all__ = ["CHANNELS", "LAYOUT", "PROTOCOLS", "SIM_CHANNELS", "FoxgloveLive", "ProtocolFront"]

log = logging.getLogger("spade.ros")

CHANNELS = {
    "map": ("/map", "nav_msgs/msg/OccupancyGrid"),
    "pose": ("/amcl_pose", "geometry_msgs/msg/PoseWithCovarianceStamped"),
    "goal": ("/goal_pose", "geometry_msgs/msg/PoseStamped"),
    "plan": ("/plan", "nav_msgs/msg/Path"),
    "confidence": ("/plan_confidence", "std_msgs/msg/Float32"),
    "window": ("/plan_window", "nav_msgs/msg/OccupancyGrid"),
    "probability": ("/plan_probability", "nav_msgs/msg/OccupancyGrid"),
    "tf": ("/tf", "tf2_msgs/msg/TFMessage"),
}
#: What the desk simulator's own server carries (the plans it reads from the node; the windows are the node's).
SIM_CHANNELS = ("map", "pose", "goal", "plan", "tf")
#: The Foxglove layout for the node, its recordings and the simulator (shipped in the package; on the site too).
LAYOUT = Path(__file__).with_name("foxglove_layout.json")
#: The WebSocket subprotocols accepted: the SDK's name, then the same protocol's older name.
PROTOCOLS = ("foxglove.sdk.v1", "foxglove.websocket.v1")
SDK_PROTOCOLS = ("foxglove.sdk.v1", "foxglove.sdk.v1.1")


def _msgdef(typename: str, store: list = []) -> bytes:  # noqa: B006 - the typestore, loaded once
    if not store:
        from rosbags.typesys import Stores, get_typestore

        store.append(get_typestore(Stores.ROS2_HUMBLE))
    return store[0].generate_msgdef(typename, ros_version=2)[0].encode()


# -- the protocol names -------------------------------------------------------------------------------------------
def _header(head: bytes, name: bytes) -> list[bytes]:
    """The comma-separated values of an HTTP header (every occurrence), lower-cased."""
    values: list[bytes] = []
    for line in head.split(b"\r\n")[1:]:
        key, sep, value = line.partition(b":")
        if sep and key.strip().lower() == name:
            values += [v.strip().lower() for v in value.split(b",") if v.strip()]
    return values


def _set_header(head: bytes, name: bytes, value: bytes) -> bytes:
    """``head`` with the header ``name`` (every occurrence) replaced by one line ``name: value``."""
    lines = head.split(b"\r\n")
    kept = [lines[0]] + [ln for ln in lines[1:] if ln.partition(b":")[0].strip().lower() != name.lower()]
    end = kept.index(b"") if b"" in kept else len(kept)
    return b"\r\n".join(kept[:end] + [name + b": " + value] + kept[end:])


class ProtocolFront:
    """The server's public port: a TCP front of the SDK's server (on loopback) that takes both protocol names.

    A WebSocket upgrade offering ``foxglove.sdk.v1`` passes unchanged; one offering only ``foxglove.websocket.v1``
    (the same protocol under its old name) is passed on as ``foxglove.sdk.v1`` and answered with the name it asked
    for; one offering neither gets HTTP 400 saying which names are spoken (logged once, later ones at debug level).
    """

    def __init__(self, host: str, port: int, upstream_port: int) -> None:
        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        try:
            self.sock = socket.create_server((host, int(port)), family=family)
        except OSError as err:
            raise ConfigError(f"foxglove_port={port}: cannot listen on {host}:{port} ({err.strerror or err}); "
                              "another node, simulator or app holds it: choose another foxglove_port (0: any free "
                              "port)") from None
        self.port = int(self.sock.getsockname()[1])
        self.upstream = ("127.0.0.1", int(upstream_port))
        self.refusals = 0
        self._open: set[socket.socket] = set()
        self._lock = threading.Lock()
        self._closed = False
        threading.Thread(target=self._accept, name="foxglove-front", daemon=True).start()

    def _accept(self) -> None:
        while not self._closed:
            try:
                conn, addr = self.sock.accept()
            except OSError:
                return
            threading.Thread(target=self._serve, args=(conn, addr), name="foxglove-client", daemon=True).start()

    def _track(self, *socks: socket.socket, add: bool = True) -> None:
        with self._lock:
            for s in socks:
                (self._open.add if add else self._open.discard)(s)

    @staticmethod
    def _read_head(sock: socket.socket) -> tuple[bytes, bytes]:
        """An HTTP head (up to its blank line) and what came after it."""
        data = b""
        while b"\r\n\r\n" not in data:
            chunk = sock.recv(4096)
            if not chunk or len(data) > 65536:
                raise ConnectionError("no HTTP head")
            data += chunk
        head, _, rest = data.partition(b"\r\n\r\n")
        return head, rest

    def _serve(self, conn: socket.socket, addr: Any) -> None:
        up = None
        try:
            conn.settimeout(10.0)
            head, rest = self._read_head(conn)
            offered = _header(head, b"sec-websocket-protocol")
            legacy = b"foxglove.websocket.v1"
            upgrade = b"websocket" in _header(head, b"upgrade")
            if upgrade and not any(p.encode() in offered for p in (*SDK_PROTOCOLS, "foxglove.websocket.v1")):
                self._refuse(conn, addr, offered)
                return
            rename = upgrade and legacy in offered and not any(p.encode() in offered for p in SDK_PROTOCOLS)
            if rename:
                head = _set_header(head, b"Sec-WebSocket-Protocol", SDK_PROTOCOLS[0].encode())
            up = socket.create_connection(self.upstream, timeout=10.0)
            self._track(conn, up)
            up.sendall(head + b"\r\n\r\n" + rest)
            if rename:
                reply, after = self._read_head(up)
                if _header(reply, b"sec-websocket-protocol"):
                    reply = _set_header(reply, b"Sec-WebSocket-Protocol", legacy)
                conn.sendall(reply + b"\r\n\r\n" + after)
            conn.settimeout(None)
            up.settimeout(None)
            back = threading.Thread(target=_pipe, args=(up, conn), name="foxglove-client-out", daemon=True)
            back.start()
            _pipe(conn, up)
            back.join()
        except (OSError, ConnectionError) as err:
            log.debug("Foxglove client %s: %s", addr, err)
        finally:
            for s in (conn, up):
                if s is not None:
                    self._track(s, add=False)
                    with contextlib.suppress(OSError):
                        s.close()

    def _refuse(self, conn: socket.socket, addr: Any, offered: list[bytes]) -> None:
        names = ", ".join(p.decode(errors="replace") for p in offered) or "none"
        reason = (f"this Foxglove server speaks the WebSocket protocols {', '.join(PROTOCOLS)}; the client offered "
                  f"{names}: connect with Foxglove (Open connection -> Foxglove WebSocket) or another viewer that "
                  "speaks one of them")
        body = reason.encode() + b"\n"
        conn.sendall(b"HTTP/1.1 400 Bad Request\r\nContent-Type: text/plain; charset=utf-8\r\nConnection: close\r\n"
                     b"Content-Length: " + str(len(body)).encode() + b"\r\n\r\n" + body)
        self.refusals += 1
        if self.refusals == 1:
            log.warning("Foxglove: refused a client at %s: %s (said once; later refusals are logged at debug level)",
                        addr[0] if isinstance(addr, tuple) else addr, reason)
        else:
            log.debug("Foxglove: refused a client at %s (protocols %s)", addr, names)

    def close(self) -> None:
        self._closed = True
        with contextlib.suppress(OSError):
            self.sock.close()
        with self._lock:
            open_socks = list(self._open)
        for s in open_socks:
            with contextlib.suppress(OSError):
                s.shutdown(socket.SHUT_RDWR)


def _pipe(src: socket.socket, dst: socket.socket) -> None:
    """Copy ``src`` to ``dst`` until ``src`` ends; then end ``dst``'s sending side."""
    try:
        with contextlib.suppress(OSError):
            while data := src.recv(65536):
                dst.sendall(data)
    finally:
        with contextlib.suppress(OSError):
            dst.shutdown(socket.SHUT_WR)


# -- the server ---------------------------------------------------------------------------------------------------
class FoxgloveLive:
    """A Foxglove WebSocket server fed by the node (:class:`spade.ros.node.PlannerNode` observer) or the simulator.

    ``channels``: the keys of :data:`CHANNELS` it advertises and carries (default: all of them); a message for
    another key is dropped. Every channel is latched (see the module docstring)."""

    def __init__(self, host: str = "127.0.0.1", port: int = 8765, channels: Iterable[str] | None = None) -> None:
        import foxglove

        keys = list(CHANNELS) if channels is None else list(channels)
        unknown = sorted(set(keys) - set(CHANNELS))
        if unknown:
            raise ValueError(f"FoxgloveLive channels {unknown}: not among {list(CHANNELS)}")
        self.context = foxglove.Context()
        self._latest: dict[str, dict[str, tuple[bytes, int | None]]] = {}
        self._lock = threading.Lock()
        self.server = foxglove.start_server(name="spade", host="127.0.0.1", port=0, context=self.context,
                                            server_listener=_latch(self))
        try:
            self.front = ProtocolFront(host, port, self.server.port)
        except BaseException:
            self.server.stop()
            raise
        self.port = self.front.port
        self.channels: dict[str, Any] = {}
        self._keys_by_topic: dict[str, str] = {}
        for key in keys:
            topic, typename = CHANNELS[key]
            schema = foxglove.Schema(name=typename, encoding="ros2msg", data=_msgdef(typename))
            self.channels[key] = foxglove.Channel(topic, message_encoding="cdr", schema=schema, context=self.context)
            self._keys_by_topic[topic] = key
        log.info("live Foxglove on ws://%s:%d (Foxglove: Open connection -> Foxglove WebSocket; layout %s)",
                 host, self.port, LAYOUT)

    def log(self, key: str, msg: Any, slot: str = "", log_time: int | None = None) -> None:
        """Send ``msg`` on channel ``key`` and keep it as the channel's latched message (one per ``slot``: the
        child frame on ``/tf``)."""
        channel = self.channels.get(key)
        if msg is None or channel is None:
            return
        data = bytes(msg.serialize())
        with self._lock:
            self._latest.setdefault(key, {})[slot] = (data, log_time)
        channel.log(data, log_time=log_time)

    def resend(self, topic: str) -> int:
        """Send a channel's latched messages again (to a new subscriber); returns how many."""
        key = self._keys_by_topic.get(topic)
        if key is None:
            return 0
        with self._lock:
            latest = list(self._latest.get(key, {}).values())
        for data, log_time in latest:
            self.channels[key].log(data, log_time=log_time)
        return len(latest)

    def _tf(self, xy_yaw: Any, parent: str, child: str, ns: int | None = None) -> None:
        self.log("tf", M.tf_message(xy_yaw, parent, child, ns), slot=child)

    # -- observer interface ----------------------------------------------------------------------------------------
    def on_message(self, name: str, msg: Any) -> None:
        if name in ("map", "goal"):
            self.log(name, msg)
        elif name == "pose":
            if type(msg).__name__ == "PoseWithCovarianceStamped":
                self.log("pose", msg)
                pose = msg.pose.pose
            else:
                pose = msg.pose
            q = pose.orientation
            yaw = quaternion_to_yaw(q.x, q.y, q.z, q.w)
            self._tf((pose.position.x, pose.position.y, yaw), msg.header.frame_id or "map", "base_link")

    def on_plan(self, event: Any, path: Any) -> None:
        self.log("plan", path)
        confidence = getattr(event, "confidence", None)
        if confidence is not None and np.isfinite(confidence):
            self.log("confidence", M.Float32(float(confidence)))
        result = getattr(event, "result", None)
        if result is None or "window" not in self.channels:
            return
        grids = window_grids(result, event.stamp_ns)
        if grids is not None and getattr(result, "pose", None) is not None:
            self._tf(result.pose, event.frame_id, WINDOW_FRAME, event.stamp_ns)
            self.log("window", grids[0])
            self.log("probability", grids[1])

    def close(self) -> None:
        self.front.close()
        with contextlib.suppress(Exception):  # shutting down
            self.server.stop()


def _latch(live: FoxgloveLive) -> Any:
    """The server listener that hands each new subscription its channel's latched messages."""
    from foxglove.websocket import ServerListener

    class Latch(ServerListener):
        def on_subscribe(self, client: Any, channel: Any) -> None:
            try:
                live.resend(channel.topic)
            except Exception as err:  # noqa: BLE001 - a viewer must never stop the node
                log.warning("Foxglove: re-sending %s to a new subscriber failed: %s: %s", channel.topic,
                            type(err).__name__, err)

    return Latch()
