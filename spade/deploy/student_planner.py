"""Plan with a trained student: a map, a robot pose and a goal in, waypoints in map metres out.

A query becomes the student's robot-frame window (:mod:`spade.deploy.robot_window`: the map resampled and rotated
about the robot, the goal placed ``margin_m`` inside it or clipped), the frame being the one the model file records
(``data.frame``; a model trained on the older axis-aligned windows is refused: retrain it). This module is the
network's part: the window is encoded as in the dataset (occupancy ``code * 0.5``, the start disc at the robot's
pixel and the goal disc at the goal's window pixel, ``rasterize.render``, radius ``disc_radius_m``), run through
the student and its path read back. The robot the planner drives is checked against the one the student was trained
for by :mod:`spade.deploy.footprint`.

The path is decoded by search (``decode="search"``, the default; :class:`spade.metrics.decoding.PathDecoder`):
the minimum-cost path over ``-log p`` plus the window costmap's inflation from the robot's pixel to the goal's
centre, never through a non-free cell, smoothed with the annotation tool's smoother. It always reaches the goal
when a free path exists in the window, and carries its confidence (the share of its length through pixels with
``p < 0.5``, the lowest ``p`` along it); ``fallback="shortest"`` returns the Nav2-like shortest path, flagged,
when that share exceeds ``low_confidence_share``. ``decode="skeleton"`` keeps the paper's extraction
(:func:`spade.metrics.extraction.extract_path`: threshold, skeleton, longest chain from the start). Every way a
query can fail gives a :class:`~spade.deploy.plan_result.PlanResult` with ``success=False``, a short ``code`` and a
readable ``reason``, keeping whatever was computed (window, probabilities) for debugging.

Replanning: a robot plans again as it drives, and a query may pass the robot's previous plan to the same goal
(``previous``, map metres: the node, the Nav2 action and the closed loop do). Its part ahead of the robot, in the
new window's pixels (:meth:`~spade.deploy.robot_window.WindowPlanner.previous_in_window`), is the search decoder's
prior (``replan_prior``, :mod:`spade.metrics.decoding`): the plan keeps the turn it chose unless the network now
finds that turn far less likely than another or the map blocks it. ``replan_prior=0`` turns it off; a query
without ``previous`` (a single plan, ``spade.plan``) is decoded as before.

Model files: a checkpoint from ``python -m spade.train``, or its ONNX / TorchScript export
(``python -m spade.export``), opened by :func:`spade.models.modelfile.open_model` (one device policy). Where torch
is not installed (a deploy install, :mod:`spade.deploy.lean`) ONNX students are opened by
:mod:`spade.deploy.onnx_runtime` (onnxruntime alone) and importing this module imports no torch.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from spade.data.encoding import MARKER_ENCODINGS, marker_channels
from spade.data.polyline import resample_polyline
from spade.data.rasterize import render
from spade.deploy.footprint import check_footprint, describe_footprint
from spade.deploy.lean import LEAN, ModelFileError, UnsafeModelFileError, open_model, robot_frame
from spade.deploy.plan_result import PlannerConfigError, PlanResult, failed_plan
from spade.deploy.robot_window import DEFAULT_MARGIN_M, PlanWindow, WindowPlanner
from spade.maps.frame import RobotFrame
from spade.maps.occupancy import FREE
from spade.metrics.decoding import PathDecoder
from spade.metrics.extraction import extract_path

__all__ = ["DEFAULT_DISC_RADIUS_M", "DEFAULT_REPLAN_PRIOR", "Planner"]

# The annotation tool's default (conf/annotate.yaml): what a model file that does not record it was trained on.
DEFAULT_DISC_RADIUS_M = 0.1
DEFAULT_REPLAN_PRIOR = 0.9
"""``replan_prior``'s default: the share of ``-log p`` taken off on the previous plan when replanning (measured:
docs/results/records/replanning/; 0 turns the prior off)."""
DEFAULT_REPLAN_KEEP = 1.0
"""``replan_keep``'s default: a replan keeps the previous plan unless a fresh path costs less than half of it
(measured with the prior in docs/results/replanning.md: fewer mode switches and a lower closed-loop APE on every
student; None turns it off)."""


def _blocked(codes: np.ndarray, points: np.ndarray, start_px: np.ndarray, goal_px: np.ndarray) -> int:
    """Points of a window path on non-free cells, other than the robot's and the goal's own cells."""
    cells = np.rint(np.asarray(points, np.float64)).astype(np.int64)
    cells[:, 0] = np.clip(cells[:, 0], 0, codes.shape[1] - 1)
    cells[:, 1] = np.clip(cells[:, 1], 0, codes.shape[0] - 1)
    ends = {tuple(np.rint(start_px).astype(np.int64)), tuple(np.rint(goal_px).astype(np.int64))}
    return int(sum(codes[r, c] != FREE and (c, r) not in ends for c, r in cells))



def _sigmoid(x: np.ndarray) -> np.ndarray:
    return (0.5 * (1.0 + np.tanh(0.5 * x))).astype(np.float32)



class Planner(WindowPlanner):
    """A trained student as a path planner (see the module docstring for how queries become windows).

    Args:
        model: a student checkpoint (``.ckpt``, from ``python -m spade.train``) or its export (``.onnx``, ``.pt``).
        device: ``cpu``, ``cuda[:N]`` or ``auto`` (:func:`spade.models.modelfile.resolve_device`).
        num_waypoints: points of the returned polyline.
        decode: ``search`` (default: the minimum-cost path over ``-log p`` on the window's costmap, robot to
            goal, :class:`~spade.metrics.decoding.PathDecoder`) or ``skeleton`` (the paper's extraction).
        fallback: None (default) or ``shortest``: a plan whose ``low_share`` exceeds ``low_confidence_share`` is
            replaced by the Nav2-like shortest path on the window's inflated costmap, flagged ``fallback=True``.
        low_confidence_share: the share of a decoded path's length through pixels with ``p < threshold`` above
            which the plan is flagged ``low_confidence`` (default 0.1).
        threshold, max_gap, goal_tolerance_px: :func:`spade.metrics.extraction.extract_path` options (the evaluation's);
            ``threshold`` is also the decoder's confidence threshold.
        disc_radius_m, margin_m: the annotation tool's ``instances.disc_radius_m`` and ``window.margin_m`` the
            student was trained with (defaults: conf/annotate.yaml's, unless the model file records them).
        far_goal: ``fail`` (default) or ``clip`` (plan to the farthest free point towards the goal that fits).
        require_goal: a path that does not reach the goal (within ``goal_tolerance_px``) is a failure.
        collision_check: a path over a non-free cell of the window (occupied or unknown) is a failure.
        batch_size: windows per forward pass in :meth:`plan_batch`.
        threads: onnxruntime intra-op threads for an ONNX model (None: its default).
        robot_radius_m, inflation_radius_m: the robot this planner drives (None: not checked). The model file
            records the footprint its demonstrations assumed (``data.footprint``, :attr:`footprint`); a robot that
            differs is refused, or only warned about with ``footprint_mismatch="warn"``.
        footprint_mismatch: ``refuse`` (default) or ``warn``.
        allow_unsigned: open an export that carries no integrity record (weight digest, parity probe, the digests
            of the fields above), with a warning, instead of refusing it (:mod:`spade.models.onnx_check`).
        replan_prior: the pull of a replan towards the robot's previous plan, in [0, 1) (search decoding): on the
            previous plan each pixel's ``-log p`` is scaled by ``1 - replan_prior`` (less farther from it), so a
            replan keeps the turn it chose while the network still finds it plausible, and changes it where the
            network gives it a ``-log p`` more than ``1 / (1 - replan_prior)`` times another way's, or where the map
            blocks it (:mod:`spade.metrics.decoding`, replanning). 0 turns it off: every replan decides afresh. Used
            only when a query passes ``previous`` (the node, the Nav2 action and the closed loop do; one plan has
            none).
        replan_keep: hysteresis on the whole plan (default :data:`DEFAULT_REPLAN_KEEP`; None: off): a replan returns the previous plan itself, joined
            from the robot, unless a fresh path costs less than ``1 / (1 + replan_keep)`` of it or the map blocks it
            (:mod:`spade.metrics.decoding`, keeping the plan). Measured in ``docs/results/replanning.md``.
    """

    def __init__(
        self,
        model: str | Path,
        *,
        device: str = "cpu",
        num_waypoints: int = 64,
        threshold: float = 0.5,
        max_gap: float = 2.0,
        goal_tolerance_px: float = 4.0,
        disc_radius_m: float | None = None,
        margin_m: float | None = None,
        far_goal: str = "fail",
        require_goal: bool = True,
        collision_check: bool = True,
        batch_size: int = 64,
        threads: int | None = None,
        decode: str = "search",
        fallback: str | None = None,
        low_confidence_share: float = 0.1,
        robot_radius_m: float | None = None,
        inflation_radius_m: float | None = None,
        footprint_mismatch: str = "refuse",
        allow_unsigned: bool = False,
        replan_prior: float = DEFAULT_REPLAN_PRIOR,
        replan_keep: float | None = DEFAULT_REPLAN_KEEP,
    ) -> None:
        path = Path(model).expanduser()
        if not path.is_file():
            raise FileNotFoundError(f"planner model {path} does not exist; pass a student checkpoint (.ckpt) from "
                                    "python -m spade.train or its export (.onnx / .pt) from python -m spade.export")
        self.path = path
        try:
            if not isinstance(allow_unsigned, bool):
                raise PlannerConfigError(f"allow_unsigned must be true or false, got {allow_unsigned!r}")
            self.backend = open_model(path, device, threads, role="student", allow_unsigned=allow_unsigned)
            frame = RobotFrame.from_json(robot_frame(self.backend.info, path))
        except UnsafeModelFileError:
            raise
        except ModelFileError as err:
            raise PlannerConfigError(str(err)) from None
        data = dict(self.backend.info["data"])
        size = [int(v) for v in data["image_size"]]
        if size != [frame.size, frame.size]:
            raise PlannerConfigError(f"{path}: image_size {size} disagrees with its robot frame's "
                                     f"{frame.size} px window; the file was not written by SPADE")
        resolution = float(data["resolution_m"])
        if not (math.isfinite(resolution) and resolution > 0):
            raise PlannerConfigError(f"{path}: resolution_m must be a positive number of metres per pixel, "
                                     f"got {data['resolution_m']!r}")
        self.disc_radius_m = float(disc_radius_m if disc_radius_m is not None
                                   else data.get("disc_radius_m", DEFAULT_DISC_RADIUS_M))
        self.marker_encoding = str(data.get("marker_encoding", "binary"))  # the model's own: never another one
        if self.marker_encoding not in MARKER_ENCODINGS:
            raise PlannerConfigError(f"{path}: marker_encoding {self.marker_encoding!r} is not one this SPADE draws "
                                     f"({list(MARKER_ENCODINGS)}); update SPADE or retrain the model")
        super().__init__(frame, resolution, far_goal=far_goal, num_waypoints=num_waypoints,
                         margin_m=float(margin_m if margin_m is not None else data.get("margin_m", DEFAULT_MARGIN_M)))
        if batch_size < 1:
            raise PlannerConfigError(f"batch_size must be >= 1, got {batch_size}")
        if decode not in ("search", "skeleton"):
            raise PlannerConfigError(f"decode must be 'search' (the planner's search decoder) or 'skeleton' (the "
                                     f"paper's extraction), got {decode!r}")
        if fallback not in (None, "none", "shortest"):
            raise PlannerConfigError(f"fallback must be null or 'shortest', got {fallback!r}")
        if LEAN and fallback == "shortest":
            raise PlannerConfigError("fallback='shortest' needs torch (spade.metrics.baselines), which this deploy "
                                     "install lacks; use fallback=null or install torch")
        if not 0.0 <= float(low_confidence_share) <= 1.0:
            raise PlannerConfigError(f"low_confidence_share must lie in [0, 1], got {low_confidence_share}")
        if (isinstance(replan_prior, bool) or not isinstance(replan_prior, (int, float))
                or not 0 <= float(replan_prior) < 1):
            raise PlannerConfigError(f"replan_prior={replan_prior!r}: a share in [0, 1), e.g. "
                                     f"replan_prior={DEFAULT_REPLAN_PRIOR:g} (0: every replan decides afresh)")
        if replan_keep is not None and (isinstance(replan_keep, bool) or not isinstance(replan_keep, (int, float))
                                        or not (math.isfinite(replan_keep) and replan_keep >= 0)):
            raise PlannerConfigError(f"replan_keep={replan_keep!r}: a ratio >= 0, e.g. replan_keep=0.2 (keep the "
                                     "previous plan unless a fresh one is 20 % cheaper), or null (off)")
        self.decode = decode
        self.fallback = None if fallback in (None, "none") else fallback
        self.low_confidence_share = float(low_confidence_share)
        # The endpoints were checked free on the map; the window's conservative rotation may still mark the robot's
        # or the goal's own cell non-free (2 x 2 footprint), which must not make a feasible plan fail.
        self.decoder = PathDecoder(num_points=num_waypoints, threshold=threshold, force_endpoints=True,
                                   prior_weight=float(replan_prior),
                                   keep_ratio=None if replan_keep is None else float(replan_keep))
        self.threshold, self.max_gap = float(threshold), float(max_gap)
        self.goal_tolerance_px = float(goal_tolerance_px)
        self.require_goal, self.collision_check = bool(require_goal), bool(collision_check)
        self.batch_size = int(batch_size)
        self.footprint = check_footprint(data.get("footprint"), robot_radius_m, inflation_radius_m,
                                         footprint_mismatch, path)

    @property
    def replan_prior(self) -> float:
        """The pull towards the previous plan when replanning, in [0, 1) (0: off); see the class docstring."""
        return self.decoder.prior_weight

    def __repr__(self) -> str:
        h, w = self.image_size
        return (f"Planner({self.path.name}, {h}x{w} px robot-frame windows at {self.resolution} m/px, "
                f"{describe_footprint(self.footprint)})")

    # -- network ---------------------------------------------------------------------------------------------
    def predict(self, states: np.ndarray) -> np.ndarray:
        """Path probabilities (N, H, W) of network inputs (N, 3, H, W), in chunks of ``batch_size``."""
        states = np.asarray(states, dtype=np.float32)
        if states.ndim != 4 or states.shape[1] != 3 or tuple(states.shape[2:]) != self.image_size:
            raise ValueError(f"states must be (N, 3, {self.image_size[0]}, {self.image_size[1]}), got {states.shape}")
        out = [self.backend.logits(states[i: i + self.batch_size]) for i in range(0, len(states), self.batch_size)]
        return _sigmoid(np.concatenate(out)[:, 0]) if out else np.zeros((0, *self.image_size), np.float32)

    def plan_windows(self, queries: list[tuple[PlanWindow, np.ndarray, np.ndarray, np.ndarray, bool]],
                     priors: Sequence[np.ndarray | None] | None = None) -> list[PlanResult]:
        """The student's plans in prepared windows: their states through the network in one pass, each decoded
        (towards its previous plan in ``priors``, when given)."""
        robot_px = np.asarray(self.frame.robot_px, dtype=np.float64)
        states = np.stack([self.encode(w.occupancy(), robot_px, g) for w, _, g, _, _ in queries])
        probs = self.predict(states)
        priors = [None] * len(queries) if priors is None else list(priors)
        return [self._extract(window, state, prob, pose, goal_px, goal_m, subgoal, prior)
                for (window, pose, goal_px, goal_m, subgoal), state, prob, prior in zip(queries, states, probs, priors)]

    # -- steps -----------------------------------------------------------------------------------------------
    def encode(self, occupancy: np.ndarray, start_px: np.ndarray, goal_px: np.ndarray) -> np.ndarray:
        """The (3, S, S) float32 network input of a window: occupancy code * 0.5, start and goal markers drawn with
        the model's ``marker_encoding`` (binary discs, or at their exact sub-pixel position)."""
        occupancy = np.asarray(occupancy, dtype=np.uint8)
        state = np.empty((3, *occupancy.shape), dtype=np.float32)
        np.multiply(occupancy, np.float32(0.5), out=state[0])
        if self.marker_encoding == "binary":
            # The annotation tool's own rasteriser draws the discs, so they are the training discs pixel for pixel.
            inst = render(occupancy, np.stack([start_px, goal_px]), self.disc_radius_m / self.resolution, 2)
            state[1] = inst.start
            state[2] = inst.goal
        else:
            state[1:] = marker_channels(start_px, goal_px, occupancy.shape[0], self.disc_radius_m / self.resolution,
                                        self.marker_encoding)
        return state

    def _extract(self, window: PlanWindow, state: np.ndarray, prob: np.ndarray, pose: np.ndarray,
                 goal_px: np.ndarray, goal_m: np.ndarray, subgoal: bool, prior: np.ndarray | None = None
                 ) -> PlanResult:
        if self.decode == "search":
            return self._search(window, state, prob, pose, goal_px, goal_m, subgoal, prior)
        return self._skeleton(window, state, prob, pose, goal_px, goal_m, subgoal)

    def _search(self, window: PlanWindow, state: np.ndarray, prob: np.ndarray, pose: np.ndarray,
                goal_px: np.ndarray, goal_m: np.ndarray, subgoal: bool, prior: np.ndarray | None = None
                ) -> PlanResult:
        start_px = np.asarray(self.frame.robot_px, dtype=np.float64)
        codes = np.rint(state[0] * 2).astype(np.uint8)
        found = self.decoder(prob, codes, start_px, goal_px, self.resolution, prior=prior)
        common = dict(pose=pose, start=pose[:2].copy(), goal=np.asarray(goal_m, dtype=np.float64), subgoal=subgoal,
                      window=window, state=state, probability=prob, extraction=found, decode="search",
                      prior=found.prior)
        if not found.ok:
            what = {"start_blocked": "the robot's cell in the window is not free",
                    "goal_blocked": "the goal's cell in the window is not free"}.get(
                found.failure, "no collision-free path joins the robot and the goal inside the student's window")
            return failed_plan("no_free_path", f"no path: {what}", **common)
        low = found.low_confidence(self.low_confidence_share)
        result = dict(low_share=found.low_share, min_probability=found.min_prob, low_confidence=low,
                      blocked=_blocked(codes, found.points, start_px, goal_px))
        if low and self.fallback == "shortest":
            from spade.metrics.baselines import shortest_path  # imports torch: only for this fallback

            line = shortest_path(codes, start_px, goal_px, self.resolution)
            if line is not None:  # from the grid cells of the ends to the exact robot and goal positions
                points = resample_polyline(np.vstack([start_px, line[1:-1], goal_px]), self.num_waypoints)
                return PlanResult(success=True, waypoints=window.to_world(points), pixels=points, fallback=True,
                                  **result, **common)
        return PlanResult(success=True, waypoints=window.to_world(found.points), pixels=found.points, **result,
                          **common)

    def _skeleton(self, window: PlanWindow, state: np.ndarray, prob: np.ndarray, pose: np.ndarray,
                  goal_px: np.ndarray, goal_m: np.ndarray, subgoal: bool) -> PlanResult:
        start_px = np.asarray(self.frame.robot_px, dtype=np.float64)
        found = extract_path(prob, start_px, goal_px, self.num_waypoints, threshold=self.threshold,
                             max_gap=self.max_gap, goal_tolerance=self.goal_tolerance_px)
        common = dict(pose=pose, start=pose[:2].copy(), goal=np.asarray(goal_m, dtype=np.float64), subgoal=subgoal,
                      window=window, state=state, probability=prob, extraction=found, decode="skeleton")
        if not found.ok:
            why = {"empty": f"no pixel of the predicted path reaches probability {self.threshold}",
                   "too_short": "the predicted path near the start is a single pixel"}.get(found.failure, found.failure)
            return failed_plan(found.failure or "empty", f"no path extracted: {why}", **common)
        away = float(np.linalg.norm(found.points[0] - start_px))
        if away > self.goal_tolerance_px:  # the predicted path lies elsewhere: not a path the robot can drive
            return failed_plan("start_not_reached", f"the predicted path begins {away * self.resolution:.2f} m from the "
                            "robot", **common)
        if self.require_goal and not found.reached_goal:
            end = found.pixels[-1]
            gap = float(np.linalg.norm(end - goal_px)) * self.resolution
            return failed_plan("goal_not_reached", f"the predicted path stops {gap:.2f} m from the goal", **common)
        occupancy = state[0]
        cells = np.vstack([found.pixels, found.points])
        cols = np.clip(np.rint(cells[:, 0]).astype(np.int64), 0, occupancy.shape[1] - 1)
        rows = np.clip(np.rint(cells[:, 1]).astype(np.int64), 0, occupancy.shape[0] - 1)
        blocked = int((occupancy[rows, cols] != np.float32(FREE * 0.5)).sum())
        if self.collision_check and blocked:
            return failed_plan("collision", f"the predicted path crosses {blocked} non-free cells", blocked=blocked,
                            **common)
        return PlanResult(success=True, waypoints=window.to_world(found.points), pixels=found.points,
                          blocked=blocked, **common)
