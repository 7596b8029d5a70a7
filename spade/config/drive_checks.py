"""The closed loop's checks: every ``drive.*`` option (conf/drive/default.yaml) typed and ranged, for
``spade.evaluate closed_loop=true`` and for each condition of ``spade.closed_loop``, and ``spade.closed_loop``'s own
``sources``, ``datasets`` and ``conditions``: all before any MLflow run opens (a bad value checked inside the drive
left a FAILED run, or none: ``scenarios=0``, ``baselines=shortest`` read as the letter ``s``, a negative
``commit_tol_cm``, ``mcap_episodes=-3``)."""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

from omegaconf import DictConfig

from spade.config.options import read_options
from spade.config.store_checks import check_server, check_store_file, store_path
from spade.deploy.mlflow_store import mlflow_client
from spade.utils.errors import ConfigError
from spade.utils.option_checks import MISSING, check_int_value, check_number_value
from spade.utils.config import compose_config

__all__ = ["ClosedLoopOptions", "EvaluateDrive", "check_drive", "check_drive_config", "check_source_rows",
           "validate_closed_loop_config"]

DRIVE_DEFAULTS = "conf/drive/default.yaml"
_NONNEGATIVE = ("noise_xy_m", "noise_yaw_rad", "initial_offset_m", "initial_offset_rad", "budget_extra_s",
                "commit_tol_cm", "min_replan_interval_s")
_POSITIVE = ("replan_distance_m", "subgoal_replan_m", "goal_tolerance_m", "budget_factor")
_FOLLOWER_POSITIVE = ("speed_mps", "lookahead_m", "max_angular_rps", "dt_s")
_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")


def check_drive(drive: Mapping[str, Any], prefix: str = "drive") -> None:
    """Every ``drive`` option of ``drive`` (a plain mapping) typed and ranged; ``prefix`` names them in the
    message (``drive.scenarios``, ``conditions.perturbed.noise_xy_m``). Unknown keys are refused too."""
    from spade.closedloop.planners import BASELINE_PLANNERS

    fix = f" (see {DRIVE_DEFAULTS})"
    for key in _NONNEGATIVE:
        check_number_value(f"{prefix}.{key}", drive.get(key, MISSING), 0, fix=fix)
    for key in _POSITIVE:
        check_number_value(f"{prefix}.{key}", drive.get(key, MISSING), 0, low_open=True, fix=fix)
    check_number_value(f"{prefix}.replan_every_m", drive.get("replan_every_m", MISSING), 0, low_open=True,
                       none_ok=True, fix=fix)
    check_int_value(f"{prefix}.scenarios", drive.get("scenarios", MISSING), 1, none_ok=True,
                    fix=": null (the test set's scenarios) or how many to drive, e.g. 100")
    check_int_value(f"{prefix}.pictures", drive.get("pictures", MISSING), 0, fix=fix)
    check_int_value(f"{prefix}.mcap_episodes", drive.get("mcap_episodes", MISSING), 1, fix=", e.g. 20")
    mcap = drive.get("mcap")
    if mcap is not None and (not isinstance(mcap, str) or not mcap.strip()):
        raise ConfigError(f"{prefix}.mcap={mcap!r} is not a path; give a new .mcap file or rosbag2 folder, or null")
    baselines = drive.get("baselines", MISSING)
    if baselines is not MISSING:
        if not isinstance(baselines, (list, tuple)) or any(b not in BASELINE_PLANNERS for b in baselines):
            raise ConfigError(f"{prefix}.baselines={baselines!r} is not a list of {list(BASELINE_PLANNERS)}; set "
                              f"{prefix}.baselines=[shortest] (a list, in brackets), or [] for none")
    follower = drive.get("follower", MISSING)
    if follower is not MISSING:
        if not isinstance(follower, Mapping):
            raise ConfigError(f"{prefix}.follower={follower!r} is not a mapping{fix}")
        for key in _FOLLOWER_POSITIVE:
            check_number_value(f"{prefix}.follower.{key}", follower.get(key, MISSING), 0, low_open=True, fix=fix)
        check_number_value(f"{prefix}.follower.rotate_deg", follower.get("rotate_deg", MISSING), 0, 180, fix=fix)
    planner = drive.get("planner", MISSING)
    if planner is not MISSING and planner is not None and not isinstance(planner, Mapping):
        raise ConfigError(f"{prefix}.planner={planner!r} is not a mapping of spade.planner.Planner options, e.g. "
                          f"{prefix}.planner={{threshold: 0.5}}")


@dataclass(frozen=True)
class EvaluateDrive:
    """``spade.evaluate``'s choice of tests and, with ``closed_loop=true``, the ``drive`` section (every option
    checked by :func:`check_drive`)."""

    node: ClassVar[str] = ""
    open_loop: bool | None = None
    closed_loop: bool | None = None
    drive: Any = None

    def __post_init__(self) -> None:
        if self.open_loop is False and self.closed_loop is False:
            raise ConfigError("open_loop=false closed_loop=false leaves nothing to evaluate; set open_loop=true (the "
                              "test set's figures), closed_loop=true (drive its scenarios), or both")
        if self.closed_loop is True:
            if not isinstance(self.drive, Mapping):
                raise ConfigError(f"drive={self.drive!r} is not the drive section; use conf/drive/default.yaml's keys")
            check_drive(self.drive)


def check_drive_config(cfg: DictConfig) -> EvaluateDrive:
    """``spade.evaluate``'s drive checks: something to run (``open_loop`` or ``closed_loop``), and with
    ``closed_loop=true`` every ``drive.*`` option (:func:`check_drive`)."""
    return read_options(cfg, EvaluateDrive)


@dataclass(frozen=True)
class ClosedLoopOptions:
    """``spade.closed_loop``'s options (conf/closed_loop.yaml): ``sources`` a list of ``{table, row}`` names,
    ``datasets`` a mapping of ``{data, scenarios}``, ``conditions`` a mapping of drive settings by name (each
    checked against the drive defaults by :func:`validate_closed_loop_config`), and ``seed``."""

    node: ClassVar[str] = ""
    seed: int = 42
    sources: Any = None
    datasets: Any = None
    conditions: Any = None

    def __post_init__(self) -> None:
        check_int_value("seed", self.seed, 0, 2**32 - 1, fix=", e.g. seed=42")
        sources = self.sources
        example = "sources=[{table: guidance, row: g_full_bc_L}]"
        if not isinstance(sources, list) or not sources:
            raise ConfigError(f"sources={sources!r} is not a non-empty list of {{table, row}}; e.g. {example}")
        for i, source in enumerate(sources):
            if not isinstance(source, Mapping) or set(source) != {"table", "row"}:
                raise ConfigError(f"sources[{i}]={source!r} is not {{table: NAME, row: NAME}}; e.g. {example}")
            for key in ("table", "row"):
                value = source[key]
                if not isinstance(value, str) or not _NAME.match(value):
                    raise ConfigError(f"sources[{i}].{key}={value!r} is not a {key} name (letters, digits, _ . -); "
                                      f"e.g. {example}")
        datasets = self.datasets
        if not isinstance(datasets, Mapping) or not datasets:
            raise ConfigError(f"datasets={datasets!r} is not a mapping of scenario sets; e.g. "
                              "datasets={heldout: {data: lshape, scenarios: 100}}")
        for name, spec in datasets.items():
            if not isinstance(spec, Mapping) or not isinstance(spec.get("data"), str) or not _NAME.match(spec["data"]):
                raise ConfigError(f"datasets.{name}={spec!r} needs data: a data config name (conf/data), e.g. "
                                  f"datasets.{name}={{data: lshape, scenarios: 100}}")
            check_int_value(f"datasets.{name}.scenarios", spec.get("scenarios"), 1, none_ok=True,
                            fix=": null (the test set's scenarios) or how many to drive, e.g. 100")
        conditions = self.conditions
        if not isinstance(conditions, Mapping) or not conditions:
            raise ConfigError(f"conditions={conditions!r} is not a mapping of drive settings; e.g. conditions={{clean: "
                              "{}}")
        for name, settings in conditions.items():
            if not _NAME.match(str(name)):
                raise ConfigError(f"conditions.{name}: not a condition name (letters, digits, _ . -)")
            if not isinstance(settings, Mapping):
                raise ConfigError(f"conditions.{name}={settings!r} is not a mapping of drive settings "
                                  f"({DRIVE_DEFAULTS})")


def validate_closed_loop_config(cfg: DictConfig) -> ClosedLoopOptions:
    """``spade.closed_loop``'s checks before any drive: :class:`ClosedLoopOptions`, and each condition's drive
    settings merged over the defaults and checked as ``drive.*``; returns the options."""
    from omegaconf import OmegaConf

    options = read_options(cfg, ClosedLoopOptions)
    defaults = OmegaConf.to_container(compose_config("evaluate", []).drive, resolve=True)
    for name, settings in options.conditions.items():
        unknown = sorted(set(settings) - set(defaults))  # type: ignore[arg-type]
        if unknown:
            raise ConfigError(f"conditions.{name}.{unknown[0]}: no such drive setting; the keys are those of "
                              f"{DRIVE_DEFAULTS}")
        check_drive({**defaults, **settings}, f"conditions.{name}")  # type: ignore[dict-item]
    check_source_store(str(cfg.tracking_uri))
    check_source_rows(str(cfg.tracking_uri), options.sources, str(OmegaConf.select(cfg, "scale.name", default="")))
    return options


def _finished(client: Any, experiment_id: str, query: str, max_results: int = 1000) -> list[Any]:
    """The finished top-level runs (a baseline's child runs left out) of one experiment matching ``query``."""
    runs = client.search_runs([experiment_id], f"attributes.status = 'FINISHED'{query}", max_results=max_results)
    return [r for r in runs if not r.data.tags.get("mlflow.parentRunId")]


def check_source_rows(uri: str, sources: list[Mapping[str, str]], scale: str, shown: int = 8) -> None:
    """When no source row has a finished run in the store at ``scale``, nothing can be driven: one line naming the
    sources and the rows the store does hold (a mistyped table or row once warned and exited 0, "0 drives run").
    A source not yet trained beside others that are is left to the launch, which warns and drives the rest."""
    client = mlflow_client(uri)
    at_scale = f" and tags.scale = '{scale}'" if scale else ""
    for source in sources:
        experiment = client.get_experiment_by_name(str(source["table"]))
        if experiment is not None and _finished(client, experiment.experiment_id,
                                                f" and attributes.run_name = '{source['row']}'{at_scale}", 1):
            return
    known = sorted({f"{e.name}/{r.info.run_name}" for e in client.search_experiments()
                    for r in _finished(client, e.experiment_id, at_scale)})
    named = ", ".join(f"{s['table']}/{s['row']}" for s in sources)
    listed = ", ".join(known[:shown]) + (f" and {len(known) - shown} more" if len(known) > shown else "")
    raise ConfigError(f"sources: no finished run of {named} (table/row) in {uri}{f' at scale {scale}' if scale else ''}"
                      f", so nothing can be driven; the store's finished rows{f' at that scale' if scale else ''}: "
                      f"{listed or 'none'}; name trained rows, e.g. sources=[{{table: quickstart, row: quickstart}}], "
                      "or train the rows first (python -m spade.train +experiment=ROW)")


def check_source_store(uri: str) -> None:
    """The store the source rows were trained into: it must exist (the drives read its finished runs; opening a
    mistyped path would create an empty store and drive nothing) and be a complete MLflow store or a server that
    answers."""
    path = store_path(uri)
    if uri.startswith("sqlite:") and path is not None and not path.exists():
        raise ConfigError(f"tracking_uri={uri}: there is no MLflow store at {path}, so there are no trained rows to "
                          "drive; point tracking_uri (or SPADE_HOME / MLFLOW_TRACKING_URI) at the store the rows "
                          "were trained into, e.g. sqlite:///PATH/logs/mlflow.db")
    check_store_file("tracking_uri", uri)
    check_server("tracking_uri", uri)
