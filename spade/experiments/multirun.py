"""A paper table as one Hydra multirun: its seed list and the message it prints at its start.

``conf/experiment/table1.yaml``, ``ablation_finetune.yaml`` and ``ablation_scratch.yaml`` sweep their rows and
``seeds`` (default ``[42, 1, 2]``): ``hydra.sweeper.params.seed: ${spade_sweep:${seeds}}`` turns the list into
Hydra's sweep syntax (``42,1,2``), so each row runs once per seed, the seeds of a row one after the other. A
table's prerequisites (experts, pretrained students; :mod:`spade.experiments.prerequisites`) are registered under
names that carry no seed: the first job that needs one trains it, with that job's seed, and every later seed and
row uses the registered model. They are trained **once**, not once per seed: the spread over seeds is the
students' own, for one fixed expert.

:class:`TableStart` (a Hydra callback of those compositions) prints, before the first job, the scale, the rows,
the seeds, the instances of each dataset and an estimate of the wall time (:func:`estimate_row`), with the
prerequisites still to train (not yet in the Model Registry) counted once.

The estimate is a cost model: seconds per training step at batch 32 and 64 px (:data:`STEP_SECONDS`, measured
and written with its machine and date by ``python -m spade.perf.cost_model`` into ``cost_model.json``), scaled
by batch size and pixels, times the steps of an epoch and the epochs,
plus :data:`VALIDATION_SHARE` for validation and data loading (the quickstart's whole epochs took 8-13 % longer
than their steps) and a fixed cost per run (:func:`estimate_row`). Machines differ (two 2-core cloud machines of
the same name trained 2.1 x apart), so before a table at a scale other than tiny :class:`TableStart` times a few
steps of the reference student here (:func:`machine_speed`) and scales every cost by the ratio. A job that starts
beside the table later slows it beyond the estimate; the tiny scale's estimate is rougher (its experts are smaller
than the costs assume: an upper bound).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, ListConfig, OmegaConf

from spade.tracking.tables import get_table
from spade.deploy.export import example_states
from spade.tracking.registry import registry_name
from spade.tracking.tables import TINY_NOTICE
from spade.training.student_module import StudentModule
from spade.utils.config import compose_config
from spade.utils.timing import step_time

try:  # a Hydra callback when Hydra is there (it always is under spade.train)
    from hydra.experimental.callback import Callback
except ImportError:  # pragma: no cover
    Callback = object  # type: ignore[assignment,misc]

log = logging.getLogger(__name__)

__all__ = ["STEP_SECONDS", "TableStart", "estimate_row", "machine_speed", "row_sweep", "seed_sweep", "start_message"]

DEFAULT_SEEDS = (42, 1, 2)


def seed_sweep(seeds: Any) -> str:
    """``[42, 1, 2]`` -> ``"42,1,2"`` (Hydra's sweep of ``seed``); one int -> that int. Seeds must be distinct ints."""
    if isinstance(seeds, (list, tuple, ListConfig)):
        values = list(seeds)
    elif seeds is None:
        values = list(DEFAULT_SEEDS)
    else:
        values = [seeds]
    if not values:
        raise ValueError("seeds=[] holds no seed; give at least one, e.g. seeds=[42,1,2]")
    try:
        ints = [int(v) for v in values]
    except (TypeError, ValueError):
        raise ValueError(f"seeds={values} must be integers, e.g. seeds=[42,1,2]") from None
    if len(set(ints)) != len(ints):
        raise ValueError(f"seeds={ints} repeats a seed; each seed runs each row once")
    return ",".join(map(str, ints))


def row_sweep(rows: Any, *table_rows: str) -> str:
    """The rows of a table to run, as Hydra's sweep of ``experiment``: all of ``table_rows`` for ``rows=null``,
    else those that one of ``rows`` names or matches as a shell pattern (``rows=[t1_small_*_L,*_expert_L]``),
    in the table's order.

    Overriding ``hydra.sweeper.params.experiment`` on the command line does not work (Hydra refuses to sweep its
    own config), so a table's subset of rows is chosen with this key, like its seeds with ``seeds=``. A name or
    pattern that matches no row is an error that lists the table's rows.
    """
    import fnmatch

    if rows is None:
        return ",".join(table_rows)
    wanted = [str(r) for r in rows] if isinstance(rows, (list, tuple, ListConfig)) else [str(rows)]
    if not wanted:
        raise ValueError("rows=[] selects no row; leave rows out for all of them, or name some, e.g. rows=[t1_small_*_L]")
    unmatched = [w for w in wanted if not any(fnmatch.fnmatchcase(r, w) for r in table_rows)]
    if unmatched:
        raise ValueError(f"rows={unmatched} match no row of this table; its rows: {', '.join(table_rows)}")
    return ",".join(r for r in table_rows if any(fnmatch.fnmatchcase(r, w) for w in wanted))


def table_row_sweep(rows: Any, table: str) -> str:
    """:func:`row_sweep` over the rows of ``table`` (:attr:`spade.tracking.tables.Table.sweep_order`): a table's
    rows are listed once, in :mod:`spade.tracking.tables`."""
    return row_sweep(rows, *get_table(table).sweep_order)


OmegaConf.register_new_resolver("spade_sweep", seed_sweep, replace=True)
OmegaConf.register_new_resolver("spade_rows", row_sweep, replace=True)
OmegaConf.register_new_resolver("spade_table_rows", table_row_sweep, replace=True)


#: Where the cost model's reference step times live: measured and written, with their provenance, by
#: ``python -m spade.perf.cost_model`` (never typed here).
COST_MODEL_FILE = Path(__file__).with_name("cost_model.json")


def load_cost_model(path: Path = COST_MODEL_FILE) -> dict[str, Any]:
    """The measured cost model (``step_seconds`` per kind, batch 32 at 64 px, and how it was measured)."""
    try:
        record = json.loads(path.read_text())
        steps = {str(k): float(v) for k, v in record["step_seconds"].items()}
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
        raise RuntimeError(f"the table cost model {path} is missing or unreadable ({exc}); rebuild it with "
                           "`python -m spade.perf.cost_model`") from None
    return {**record, "step_seconds": steps}


# Seconds per training step, batch 32, 64 px windows (spade/experiments/cost_model.json).
STEP_SECONDS: dict[str, float] = load_cost_model()["step_seconds"]
VALIDATION_SHARE = 0.12  # validation epochs (15 % of the data, forward only, metrics) and data loading on top of the steps
RUN_SECONDS = 20.0  # per run: building the model, the test's first batches, pictures, checkpoints, MLflow
TEST_SECONDS_PER_INSTANCE = 0.03  # the test: predictions, APE / Hd19 / FID, the planner's decoding (README figures)
DATA_SECONDS_PER_INSTANCE = 1 / 118  # generating a missing dataset (annotation, 118 instances/s with 2 workers)


REFERENCE_KIND = "bc/medium"  # the step :func:`machine_speed` times on the machine at hand


def machine_speed(runs: int = 3) -> float:
    """How much slower than :data:`STEP_SECONDS`' machine this one trains: the median time of ``runs`` steps of a
    fresh medium BC student (batch 32, 64 px, the torch threads a run gets, after two warm-up steps) over
    ``STEP_SECONDS["bc/medium"]``. 1.0 on the machine the costs were measured on, 2.0 on one half as fast (or
    as busy); about 5 steps' time, some seconds on 2 cores."""
    import torch

    generator_state = torch.random.get_rng_state()
    try:
        torch.manual_seed(0)
        batch = {"state": example_states(32, (64, 64), seed=0),
                 "path": (torch.rand(32, 1, 64, 64) > 0.97).float()}
        seconds = step_time(StudentModule(size="medium").train(), batch, runs=runs, warmup=2)["step_ms"] / 1000
    finally:
        torch.random.set_rng_state(generator_state)  # the table's runs seed themselves; leave no trace anyway
    return seconds / STEP_SECONDS[REFERENCE_KIND]


def _kind(cfg: DictConfig) -> str:
    """The cost kind of a composed row: ``bc/<size>``, ``dbc/<size>``, ``conddbc/<size>`` or ``expert/<kind>``."""
    tags = cfg.get("tags") or {}
    if tags.get("role") == "expert":
        return "expert/uncond" if "uncond" in str(tags.get("approach", "")).lower() else "expert/cond"
    size = str(cfg.model.get("size") or "medium")
    expert = (cfg.get("requires") or {}).get("expert")
    if expert is None:
        return f"bc/{size}"
    return f"{'dbc' if 'uncond' in str(expert.experiment) else 'conddbc'}/{size}"


def _instances(generate: Any) -> int | None:
    """The instance count a data config's ``*_generate.set`` asks for (its last ``num_instances``)."""
    if not generate:
        return None
    sets = OmegaConf.to_container(generate.get("set") or [], resolve=True)
    counts = [s["num_instances"] for s in sets if isinstance(s, dict) and s.get("num_instances") is not None]
    return int(counts[-1]) if counts else None


@dataclass(frozen=True)
class RowCost:
    """The estimated cost of one run of a row, with what it rests on."""

    row: str
    kind: str
    epochs: int
    steps_per_epoch: int
    seconds: float


def estimate_row(cfg: DictConfig) -> RowCost:
    """Seconds one run of the composed row ``cfg`` takes: steps per epoch (training instances less the validation
    share, over the batch size) x epochs x the step cost of its kind (:data:`STEP_SECONDS`, scaled by batch / 32
    and (pixels / 64)^2), plus :data:`VALIDATION_SHARE`, plus :data:`RUN_SECONDS` and the test's instances."""
    kind = _kind(cfg)
    data = cfg.data
    n_train = _instances(data.get("train_generate")) or 1000
    if data.get("max_train_instances"):
        n_train = min(n_train, int(data.max_train_instances))
    batch = int(data.get("batch_size") or 32)
    steps = max(1, math.ceil(n_train * (1 - float(data.get("val_fraction") or 0.0)) / batch))
    epochs = int(cfg.trainer.get("max_epochs") or 1)
    size = int(cfg.scale.get("image_size") or 64)
    step = STEP_SECONDS.get(kind, STEP_SECONDS["bc/medium"]) * (batch / 32) * (size / 64) ** 2
    n_test = _instances(data.get("test_generate")) or 0
    seconds = steps * epochs * step * (1 + VALIDATION_SHARE) + RUN_SECONDS + n_test * TEST_SECONDS_PER_INSTANCE
    return RowCost(str(cfg.get("run_name")), kind, epochs, steps, seconds)


def _minutes(seconds: float) -> str:
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def _store_exists(uri: str) -> bool:
    if uri.startswith("sqlite:///"):
        return os.path.exists(uri[len("sqlite:///"):])
    return True  # a server or another backend: ask it


def _registered(uri: str, name: str) -> bool:
    if not _store_exists(uri):
        return False  # never create the store just to look (the first run does)
    try:
        from spade.tracking.client import mlflow_client

        return bool(mlflow_client(uri).search_model_versions(f"name='{name}'"))
    except Exception:  # noqa: BLE001 - an estimate must not stop a table
        return False


def _passed_overrides(config: DictConfig) -> list[str]:
    """The table's command-line overrides that shape its rows (not the rows, seeds or Hydra's own)."""
    try:
        task = list(config.hydra.overrides.task)
    except Exception:  # noqa: BLE001
        return []
    skip = ("experiment", "seed", "seeds", "rows", "hydra", "scale", "recipe")
    return [o for o in task if not o.split("=", 1)[0].lstrip("+~").startswith(skip)]


def _datasets(cfg: DictConfig, seen: dict[str, tuple[int, str]]) -> None:
    for split, key in (("training", "train"), ("test", "test")):
        n = _instances(cfg.data.get(f"{key}_generate"))
        directory = cfg.data.get(f"{key}_dir")
        if n and directory:
            note = split
            if key == "train":
                note += f", {int(float(cfg.data.get('val_fraction') or 0) * 100)} % of it validation"
            seen[str(directory)] = (n, note)


def plan_table(config: DictConfig, speed: float = 1.0) -> dict[str, Any]:
    """What a table's multirun will run: scale, rows, seeds, datasets, per-row and prerequisite costs and the
    total, each on :data:`STEP_SECONDS`' machine times ``speed`` (:func:`machine_speed`)."""
    params = config.hydra.sweeper.params
    rows = [r.strip() for r in str(params.experiment).split(",") if r.strip()]
    task = [str(o) for o in (OmegaConf.select(config, "hydra.overrides.task") or [])]
    given = [o.split("=", 1)[1] for o in task if o.split("=", 1)[0].lstrip("+~") == "seed"]  # seed=7 wins
    seeds = [int(s) for s in (given[-1] if given else str(params.get("seed", config.get("seed", 42)))).split(",")]
    scale = str(config.scale.name)
    overrides = [f"scale={scale}", f"recipe={config.recipe.name}", *_passed_overrides(config)]
    costs: dict[str, RowCost] = {}
    pending: dict[str, RowCost] = {}  # registry name -> cost of a prerequisite to train
    datasets: dict[str, tuple[int, str]] = {}
    uri = str(config.paths.mlflow_tracking_uri)

    def walk(cfg: DictConfig, depth: int = 0) -> None:
        for req in (cfg.get("requires") or {}).values():
            if OmegaConf.select(cfg, req.target) not in (None, "", "???") or depth > 4 or req.experiment in rows:
                continue  # given by path, or a row of this table (Table 1's experts), which trains it first
            sub = compose_config("train", [f"+experiment={req.experiment}", *overrides, "paths.output_dir=."])
            name = registry_name(sub)
            if name is None or name in pending or _registered(uri, name):
                continue
            pending[name] = estimate_row(sub)
            _datasets(sub, datasets)
            walk(sub, depth + 1)

    for row in rows:
        cfg = compose_config("train", [f"+experiment={row}", *overrides, "paths.output_dir=."])
        costs[row] = estimate_row(cfg)
        _datasets(cfg, datasets)
        walk(cfg)
    missing_data = sum(n for d, (n, _) in datasets.items() if not os.path.isdir(d))
    if not speed > 0 or not math.isfinite(speed):
        raise ValueError(f"speed={speed} must be a positive factor (1.0: the cost model's own machine)")
    if speed != 1.0:
        costs = {k: dataclasses.replace(c, seconds=c.seconds * speed) for k, c in costs.items()}
        pending = {k: dataclasses.replace(c, seconds=c.seconds * speed) for k, c in pending.items()}
    total = (sum(c.seconds for c in costs.values()) * len(seeds) + sum(c.seconds for c in pending.values())
             + missing_data * DATA_SECONDS_PER_INSTANCE * speed)
    return {"scale": scale, "rows": rows, "seeds": seeds, "costs": costs, "pending": pending,
            "datasets": datasets, "missing_data": missing_data, "total": total, "speed": speed}


def start_message(config: DictConfig, speed: float | None = None) -> str:
    """The lines a table's multirun prints at its start (:func:`plan_table`), its costs scaled by ``speed``
    (``None``: the cost model's machine, unmeasured)."""
    plan = plan_table(config, 1.0 if speed is None else speed)
    seeds, rows = plan["seeds"], plan["rows"]
    lines = [f"SPADE table run: scale={plan['scale']}, {len(rows)} rows x {len(seeds)} seed(s) "
             f"({', '.join(map(str, seeds))}) = {len(rows) * len(seeds)} runs"]
    if plan["scale"] == "tiny":
        lines.append(f"  {TINY_NOTICE}")
    lines.append("  rows: " + ", ".join(rows))
    for directory, (n, note) in plan["datasets"].items():
        exists = "" if os.path.isdir(directory) else " (to generate)"
        lines.append(f"  instances: {n:,} {note} in {directory}{exists}")
    for row, c in plan["costs"].items():
        lines.append(f"  {row}: {c.epochs} epochs x {c.steps_per_epoch} steps ({c.kind}), about "
                     f"{_minutes(c.seconds)} per seed")
    if plan["pending"]:
        lines.append("  prerequisites to train first, once for all seeds (not in the Model Registry yet): " + ", ".join(
            f"{c.row} (about {_minutes(c.seconds)})" for c in plan["pending"].values()))
    else:
        lines.append("  prerequisites: all registered (or none needed)")
    if speed is None:
        where = "on 2 quiet CPU cores like the cost model's (not measured here)"
    else:
        where = (f"on this machine, which took {speed:.2f} x the cost model's {STEP_SECONDS[REFERENCE_KIND]:.2f} s "
                 "for a medium BC step just now")
    lines.append(f"  estimated wall time: about {_minutes(plan['total'])} {where} (a cost model, "
                 "spade/experiments/multirun.py: measured step costs x steps; more if other jobs start)")
    return "\n".join(lines)


def check_sweep(config: DictConfig) -> None:
    """Resolve a table's sweep (``${spade_rows:}``, ``${spade_sweep:}``) before Hydra does: a bad ``rows=`` or
    ``seeds=`` ends the process with one ``error:`` line and exit status 2 (as :func:`exit_on_user_error` ends a
    run's), where Hydra's sweeper would print OmegaConf's traceback. ``HYDRA_FULL_ERROR=1`` shows the traceback."""
    import sys

    from omegaconf.errors import InterpolationResolutionError

    params = OmegaConf.select(config, "hydra.sweeper.params") or {}
    try:
        for key in params:
            str(params[key])
    except InterpolationResolutionError as exc:
        cause: BaseException = exc  # the resolver's own error, under OmegaConf's (raised without `from`)
        while isinstance(cause, InterpolationResolutionError) and (cause.__cause__ or cause.__context__):
            cause = cause.__cause__ or cause.__context__  # type: ignore[assignment]
        if (isinstance(cause, InterpolationResolutionError) or not isinstance(cause, ValueError)
                or os.environ.get("HYDRA_FULL_ERROR") == "1"):
            raise
        print(f"error: {cause}", file=sys.stderr, flush=True)
        raise SystemExit(2) from None


class TableStart(Callback):  # type: ignore[misc,valid-type]
    """Hydra callback of a table's composition: prints :func:`start_message` before the first job runs."""

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        check_sweep(config)
        try:
            # at tiny scale (tests, pipeline checks) the estimate is rough anyway: no timing steps
            speed = None if str(OmegaConf.select(config, "scale.name")) == "tiny" else machine_speed()
            message = start_message(config, speed)
        except Exception as exc:  # noqa: BLE001 - the message must never stop the table
            log.warning("could not estimate the table's run: %s", exc)
            return
        print(message, flush=True)
