"""What ``python -m spade.ros`` runs (``conf/ros.yaml``): the planner, the node's logic, then DDS or a replay."""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from spade.utils.errors import ConfigError
from spade.deploy.mlflow_models import resolve_model
from spade.maps import FREE, OccupancyMap
from spade.ros.core import check_option, CoreSettings, PlannerCore
from spade.ros.node_options import TOPIC_KEYS
from spade.ros.recording import NodeRecorder, replay_bag

__all__ = ["build_core", "build_planner", "checked_options", "domain_id", "foxglove_options", "require_dds", "run"]

log = logging.getLogger("spade.ros")


def _options(cfg: DictConfig, key: str) -> dict[str, Any]:
    node = cfg.get(key)
    return dict(OmegaConf.to_container(node, resolve=True)) if node is not None else {}  # type: ignore[arg-type]


def build_planner(cfg: DictConfig) -> Any:
    """The :class:`spade.planner.Planner` of ``cfg.model_path`` with ``cfg.planner``'s options; prints how long the
    import and the model took."""
    value = cfg.get("model_path")
    if value in (None, ""):
        raise ConfigError("model_path: no model; pass model=PATH (a student .ckpt from python -m spade.train, its "
                          ".onnx export from python -m spade.export, or models:/NAME@ALIAS) or set SPADE_PLANNER_MODEL")
    path = resolve_model(str(value), OmegaConf.select(cfg, "paths.mlflow_tracking_uri"),
                         OmegaConf.select(cfg, "paths.registry_cache_dir"))
    t0 = time.perf_counter()
    from spade.deploy.student_planner import Planner

    imported = time.perf_counter() - t0
    planner = Planner(path, device=str(cfg.get("device", "cpu")), **_options(cfg, "planner"))
    loaded = time.perf_counter() - t0 - imported
    warm = warm_up(planner)
    log.info("planner %r ready (import %.2f s, model %.2f s, warm-up plan %.2f s)", planner, imported, loaded, warm)
    return planner


def warm_up(planner: Any) -> float:
    """One plan on an empty map, so that the first goal does not pay for lazy imports and the runtime's first run
    (about 0.6 s on a CPU without torch); returns its seconds."""
    import numpy as np

    t0 = time.perf_counter()
    empty = OccupancyMap(np.full((80, 80), FREE, np.uint8), planner.resolution, (0.0, 0.0, 0.0), name="warm-up")
    centre = 40 * planner.resolution
    try:
        planner.plan(empty, (centre, centre, 0.0), (centre + 10 * planner.resolution, centre))
    except Exception as err:  # noqa: BLE001 - a warm-up must not stop the node; the real queries will say more
        log.warning("warm-up plan failed: %s: %s", type(err).__name__, err)
    return time.perf_counter() - t0


def build_core(cfg: DictConfig, planner: Any, settings: Any = None) -> Any:
    return PlannerCore(planner, settings if settings is not None else core_settings(cfg))


def core_settings(cfg: DictConfig) -> Any:
    """``cfg.node`` as :class:`spade.ros.core.CoreSettings`, typed and ranged (ConfigError naming the option)."""
    node = _options(cfg, "node")
    try:
        return CoreSettings(**node)
    except TypeError as err:
        raise ConfigError(f"node: {err}; the keys are those of conf/ros.yaml's node block") from None
    except ValueError as err:
        raise ConfigError(f"{err} (conf/ros.yaml's node block)") from None


def action_settings(cfg: DictConfig) -> Any:
    """``cfg.action`` as :class:`spade.ros.action.ActionSettings`, typed and ranged."""
    from spade.ros.action import ActionSettings
    from spade.ros.action_types import DISTROS
    raw = _options(cfg, "action")
    known = set(ActionSettings.__dataclass_fields__)
    unknown = sorted(set(raw) - known)
    if unknown:
        raise ConfigError(f"action.{unknown[0]}: no such option; the keys are {sorted(known)}")
    try:
        out: dict[str, Any] = {}
        if "enabled" in raw:
            out["enabled"] = check_option("action.enabled", raw["enabled"], "bool")
        if "name" in raw:
            name = check_option("action.name", raw["name"], "str")
            if not name.strip("/ ") or any(c.isspace() for c in name):
                raise ValueError(f"action.name={name!r}: a ROS 2 action name such as /compute_path_to_pose")
            out["name"] = name
        if "distro" in raw:
            distro = str(raw["distro"]).lower()
            if distro in ("kilted", "rolling"):
                distro = "jazzy"
            if distro not in DISTROS:
                raise ValueError(f"action.distro={raw['distro']!r}: the robot's ROS 2 distribution, one of "
                                 f"{list(DISTROS)} (kilted and rolling use jazzy's layout)")
            out["distro"] = distro
        for key, low, inclusive in (("wait_s", 0.0, True), ("timeout_s", 0.0, False), ("result_timeout_s", 0.0, True)):
            if key in raw:
                out[key] = check_option(f"action.{key}", raw[key], "float", low, inclusive)
        if "planner_ids" in raw:
            ids = raw["planner_ids"] or []
            if isinstance(ids, str) or not all(isinstance(v, str) for v in ids):
                raise ValueError(f"action.planner_ids={ids!r}: a list of names, e.g. [GridBased] ([]: any)")
            out["planner_ids"] = tuple(ids)
    except ValueError as err:
        raise ConfigError(f"{err} (conf/ros.yaml's action block)") from None
    return ActionSettings(**out)


def checked_options(cfg: DictConfig) -> dict[str, Any]:
    """Every option of the node, typed and ranged before any work (before the model loads or DDS starts)."""
    topics = _options(cfg, "topics")
    unknown = sorted(set(topics) - set(TOPIC_KEYS))
    if unknown:
        raise ConfigError(f"topics.{unknown[0]}: no such topic; the keys are {list(TOPIC_KEYS)}")
    for key, value in topics.items():
        if value is not None and not isinstance(value, str):
            raise ConfigError(f"topics.{key}={value!r}: a ROS 2 topic name such as /{key}")
        if value and any(c.isspace() for c in value):
            raise ConfigError(f"topics.{key}={value!r}: a ROS 2 topic name has no spaces")
    pose_type = cfg.get("pose_type", "amcl")
    if pose_type not in ("amcl", "stamped"):
        raise ConfigError(f"pose_type={pose_type!r}: use amcl (PoseWithCovarianceStamped) or stamped (PoseStamped)")
    try:
        from spade.ros.node_options import check_qos

        qos = check_qos(_options(cfg, "qos"))
    except ValueError as err:
        raise ConfigError(f"{err} (conf/ros.yaml's qos block)") from None
    max_seconds = cfg.get("max_seconds")
    if max_seconds is not None:
        try:
            from spade.ros.core import check_option

            max_seconds = check_option("max_seconds", max_seconds, "float", 0.0, False)
        except ValueError as err:
            raise ConfigError(str(err)) from None
    return {"topics": topics, "pose_type": str(pose_type), "qos": qos, "node": core_settings(cfg),
            "action": action_settings(cfg), "max_seconds": max_seconds}


def domain_id(cfg: DictConfig) -> int:
    """``domain_id`` (ROS_DOMAIN_ID) of the config, checked: an integer 0..232."""
    value = cfg.get("domain_id", 0)
    try:
        domain = int(value)
    except (TypeError, ValueError):
        raise ConfigError(f"domain_id={value!r}: a DDS domain id is an integer 0..232 (ROS_DOMAIN_ID)") from None
    if not 0 <= domain <= 232:
        raise ConfigError(f"domain_id={domain}: a DDS domain id is an integer 0..232 (ROS_DOMAIN_ID)")
    return domain


def run(cfg: DictConfig) -> dict[str, int]:
    """Run the node (or the replay) the config describes; returns the core's message and outcome counts."""
    require_dds("python -m spade.ros")  # its messages and options are DDS types, a replay's too
    options = checked_options(cfg)
    if cfg.get("replay"):
        planner = build_planner(cfg)
        core = build_core(cfg, planner, options["node"])
        return replay_bag(core, Path(str(cfg.replay)), options["topics"],
                          out=cfg.get("replay_out") and Path(str(cfg.replay_out)))
    domain = domain_id(cfg)
    from spade.ros.node import PlannerNode, Topics

    topics_cfg = Topics(**{k: str(v or "") for k, v in options["topics"].items()})
    pose_type = options["pose_type"]
    foxglove = foxglove_options(cfg)
    planner = build_planner(cfg)
    core = build_core(cfg, planner, options["node"])
    recorder = None
    if cfg.get("record"):
        recorder = NodeRecorder(Path(str(cfg.record)), topics_cfg, pose_type)
    node = PlannerNode(core, domain_id=domain, topics=topics_cfg, pose_type=pose_type, qos=options["qos"],
                       recorder=recorder, action=options["action"])
    live = None
    if foxglove is not None:
        from spade.ros.live import FoxgloveLive

        live = FoxgloveLive(**foxglove)
        node.observers.append(live)
    log.info("spade.ros node up on DDS domain %d: map %s, pose %s (%s), goal %s -> plan %s%s", domain, topics_cfg.map,
             topics_cfg.pose, pose_type, topics_cfg.goal, topics_cfg.plan,
             f"; action {options['action'].name} ({options['action'].distro} layout)" if node.action else "")
    try:
        node.spin(options["max_seconds"])
    finally:
        node.close()
        if live is not None:
            live.close()
        if recorder is not None:
            recorder.close()
            log.info("recording written to %s", recorder.path)
    log.info("spade.ros node stopped: %s", core.counts)
    return core.counts


#: The node's live Foxglove port: Foxglove's own default (its "Open connection" proposes ws://localhost:8765).
NODE_FOXGLOVE_PORT = 8765
#: The desk simulator's own Foxglove server (both run side by side).
SIM_FOXGLOVE_PORT = 8766
#: The install line of the robot side's optional packages (cyclonedds: ROS 2's DDS; foxglove-sdk: live Foxglove).
ROS_INSTALL = 'pip install "spade[ros]" (in a clone of the repository: pip install -e ".[ros]")'


def require_dds(command: str) -> None:
    """The DDS package that ``command`` (the node, the simulator) needs, or one :class:`ConfigError` naming it and
    the install line (instead of a ``ModuleNotFoundError`` traceback)."""
    try:
        import cyclonedds.domain  # noqa: F401
    except ImportError as err:
        why = "" if isinstance(err, ModuleNotFoundError) and (err.name or "").startswith("cyclonedds") else f" ({err})"
        raise ConfigError(f"{command} needs the cyclonedds package (ROS 2's DDS, no ROS install needed){why}: "
                          f"{ROS_INSTALL}") from None


def foxglove_options(cfg: DictConfig, prefix: str = "foxglove", default_port: int = NODE_FOXGLOVE_PORT,
                     host_key: str = "foxglove_host") -> dict[str, Any] | None:
    """``foxglove=true`` (and ``foxglove_host``, ``foxglove_port``): the live Foxglove server's options, or None
    (``prefix``: ``node_foxglove`` for the node that the simulator starts). Checked before any work; a missing
    foxglove-sdk is refused with the install line."""
    try:
        enabled = check_option(prefix, cfg.get(prefix, False), "bool")
        port = check_option(f"{prefix}_port", cfg.get(f"{prefix}_port", default_port), "int", 0, True, high=65535)
        host = check_option(host_key, cfg.get(host_key, "127.0.0.1"), "str")
    except ValueError as err:
        raise ConfigError(str(err)) from None
    if not enabled:
        return None
    if not str(host).strip():  # a server on "" listens nowhere a viewer can name; the run would start and fail late
        raise ConfigError(f"{host_key}={host!r} is empty; give the address the Foxglove server listens on: "
                          f"{host_key}=127.0.0.1 (this machine only) or {host_key}=0.0.0.0 (reachable from others)")
    import importlib.util

    if importlib.util.find_spec("foxglove") is None:
        raise ConfigError(f"{prefix}=true needs the foxglove-sdk package: {ROS_INSTALL}; or leave {prefix}=false")
    return {"host": host, "port": int(port)}
