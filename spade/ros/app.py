"""What ``python -m spade.ros`` runs (``conf/ros.yaml``): the planner, the node's logic, then DDS or a replay."""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from spade.utils.errors import ConfigError

__all__ = ["build_core", "build_planner", "run"]

log = logging.getLogger("spade.ros")


def _options(cfg: DictConfig, key: str) -> dict[str, Any]:
    node = cfg.get(key)
    return dict(OmegaConf.to_container(node, resolve=True)) if node is not None else {}  # type: ignore[arg-type]


def build_planner(cfg: DictConfig) -> Any:
    """The :class:`spade.planner.Planner` of ``cfg.model_path`` with ``cfg.planner``'s options; prints how long the
    import and the model took."""
    from spade.deploy.registry import resolve_model

    value = cfg.get("model_path")
    if value in (None, ""):
        raise ConfigError("model_path: no model; pass model=PATH (a student .ckpt from python -m spade.train, its "
                          ".onnx export from python -m spade.export, or models:/NAME@ALIAS) or set SPADE_PLANNER_MODEL")
    path = resolve_model(str(value), OmegaConf.select(cfg, "paths.mlflow_tracking_uri"),
                         OmegaConf.select(cfg, "paths.registry_cache_dir"))
    t0 = time.perf_counter()
    from spade.deploy.planner import Planner

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

    from spade.maps import FREE, OccupancyMap

    t0 = time.perf_counter()
    empty = OccupancyMap(np.full((80, 80), FREE, np.uint8), planner.resolution, (0.0, 0.0, 0.0), name="warm-up")
    centre = 40 * planner.resolution
    try:
        planner.plan(empty, (centre, centre, 0.0), (centre + 10 * planner.resolution, centre))
    except Exception as err:  # noqa: BLE001 - a warm-up must not stop the node; the real queries will say more
        log.warning("warm-up plan failed: %s: %s", type(err).__name__, err)
    return time.perf_counter() - t0


def build_core(cfg: DictConfig, planner: Any) -> Any:
    from spade.ros.core import CoreSettings, PlannerCore

    node = _options(cfg, "node")
    try:
        settings = CoreSettings(**node)
    except TypeError as err:
        raise ConfigError(f"node: {err}; the keys are those of conf/ros.yaml's node block") from None
    return PlannerCore(planner, settings)


def _domain_id(cfg: DictConfig) -> int:
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
    if cfg.get("replay"):
        from spade.ros.recording import replay_bag

        planner = build_planner(cfg)
        core = build_core(cfg, planner)
        return replay_bag(core, Path(str(cfg.replay)), _options(cfg, "topics"),
                          out=cfg.get("replay_out") and Path(str(cfg.replay_out)))
    from spade.ros.node import PlannerNode, Topics

    domain = _domain_id(cfg)
    topics = _options(cfg, "topics")
    try:
        topics_cfg = Topics(**{k: str(v or "") for k, v in topics.items()})
    except TypeError as err:
        raise ConfigError(f"topics: {err}; the keys are map, pose, goal, plan, confidence") from None
    pose_type = str(cfg.get("pose_type", "amcl"))
    if pose_type not in ("amcl", "stamped"):
        raise ConfigError(f"pose_type={pose_type!r}: use amcl (PoseWithCovarianceStamped) or stamped (PoseStamped)")
    planner = build_planner(cfg)
    core = build_core(cfg, planner)
    recorder = None
    if cfg.get("record"):
        from spade.ros.recording import NodeRecorder

        recorder = NodeRecorder(Path(str(cfg.record)), topics_cfg, pose_type)
    node = PlannerNode(core, domain_id=domain, topics=topics_cfg, pose_type=pose_type, qos=_options(cfg, "qos"),
                       recorder=recorder)
    log.info("spade.ros node up on DDS domain %d: map %s, pose %s (%s), goal %s -> plan %s", domain, topics_cfg.map,
             topics_cfg.pose, pose_type, topics_cfg.goal, topics_cfg.plan)
    try:
        node.spin(cfg.get("max_seconds"))
    finally:
        node.close()
        if recorder is not None:
            recorder.close()
            log.info("recording written to %s", recorder.path)
    log.info("spade.ros node stopped: %s", core.counts)
    return core.counts
