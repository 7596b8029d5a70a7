"""What every run records in MLflow besides Lightning's metrics, and how a person opens it in the MLflow UI.

* The experiment (one per paper table, quickstart, smoke, sweep or evaluation) is tagged as model-training work
  (``mlflow.experimentKind=custom_model_development``: MLflow 3 UIs otherwise open it on the GenAI traces view)
  and carries a description (``mlflow.note.content``): the paper table it reproduces and how to regenerate it.
* A run records the composed config (flattened params and ``config/train.yaml``), tags, the FID extractor's
  identity, its best and last checkpoints, its datasets as MLflow dataset inputs (``mlflow.data``: name, digest
  = the dataset's fingerprint, source = its directory, context training / validation / test, the manifest's key
  facts as the profile) and a description: row, approach, prerequisites (linked to their runs), test figures
  next to the classical baselines and the untrained model when the run logged them.
* :func:`ui_lines` gives the ``mlflow ui`` command and URLs that open a run and its experiment's runs table
  (``?workflowType=machine_learning``), printed at the end of training and by ``spade.report``. The runs table
  opens on a view stored in the experiment (:data:`VIEW_TAG`) that shows the Dataset and metric columns.
"""

from __future__ import annotations

import json
import logging
import math
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import quote, urlsplit

import lightning as L
from lightning.pytorch.loggers import Logger, MLFlowLogger
from lightning.pytorch.utilities import rank_zero_only
from omegaconf import DictConfig, OmegaConf

from spade.data.fingerprint import dataset_fingerprint
from spade.data.format import read_manifest_json

log = logging.getLogger(__name__)

KIND_TAG = "mlflow.experimentKind"
KIND_TRAINING = "custom_model_development"  # the MLflow UI's "model training" experiments
NOTE_TAG = "mlflow.note.content"  # an experiment's or a run's description in the MLflow UI
WORKFLOW_QUERY = "workflowType=machine_learning"  # MLflow 3 UIs: open on runs, not on GenAI traces
# A runs-table view stored in the experiment (the MLflow UI's "shared view": tag mlflow.sharedViewState.<key>,
# opened by ?viewStateShareKey=<key>): the Dataset column and the tables' metric columns, newest run first.
VIEW_KEY = "spade"
VIEW_TAG = f"mlflow.sharedViewState.{VIEW_KEY}"
DEFAULT_UI = "http://127.0.0.1:5000"  # where `mlflow ui` listens unless told otherwise
UI_URL_ENV = "SPADE_MLFLOW_UI_URL"  # the UI's address when it is not `mlflow ui`'s default (another port, a proxy)
REPO_CONF = Path(__file__).resolve().parents[2] / "conf"


def flatten(cfg: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested dict -> {"a/b/c": value}; lists are kept as their string form (MLflow params are strings)."""
    out: dict[str, Any] = {}
    for key, value in cfg.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(flatten(value, f"{name}/"))
        else:
            out[name] = value
    return out


def mlflow_logger(loggers: list[Logger]) -> MLFlowLogger | None:
    return next((lg for lg in loggers if isinstance(lg, MLFlowLogger)), None)


# -- links into the MLflow UI -----------------------------------------------------------------------------------
def is_server_uri(tracking_uri: str) -> bool:
    return str(tracking_uri).startswith(("http://", "https://"))


def ui_base_url(tracking_uri: str, ui_url: str | None = None) -> str:
    """The UI's address: ``ui_url``, else ``$SPADE_MLFLOW_UI_URL``, else the tracking server itself for
    ``http(s)://`` URIs, else where ``mlflow ui`` listens by default."""
    ui_url = ui_url or os.environ.get(UI_URL_ENV)
    if ui_url:
        if not str(ui_url).startswith(("http://", "https://")):
            raise ValueError(f"{UI_URL_ENV}={ui_url!r}: the MLflow UI's address must start with http:// or https://")
        return str(ui_url).rstrip("/")
    return str(tracking_uri).rstrip("/") if is_server_uri(tracking_uri) else DEFAULT_UI


def experiment_url(base: str, experiment_id: str, view: bool = True) -> str:
    """The experiment's runs table (MLflow's hash routes; the query keeps 3.x UIs off the GenAI view), with
    SPADE's view of it (:func:`runs_view_state`: metric columns shown) unless ``view=False``."""
    query = f"viewStateShareKey={VIEW_KEY}&{WORKFLOW_QUERY}" if view else WORKFLOW_QUERY
    return f"{base.rstrip('/')}/#/experiments/{experiment_id}/runs?{query}"


def runs_view_state() -> str:
    """The runs table as SPADE shows it: Dataset, the paper's test metrics and the parameter count as columns."""
    from spade.experiments.tables import METRICS

    columns = ["attributes.`Dataset`", *(f"metrics.`{m.mlflow_key}`" for m in METRICS.values())]
    return json.dumps({"selectedColumns": columns, "orderByKey": "attributes.start_time", "orderByAsc": False})


def run_url(base: str, experiment_id: str, run_id: str) -> str:
    return f"{base.rstrip('/')}/#/experiments/{experiment_id}/runs/{run_id}?{WORKFLOW_QUERY}"


def artifact_url(base: str, experiment_id: str, run_id: str, path: str) -> str:
    """A run's Artifacts tab with ``path`` selected (PNG files are shown as pictures); ``base=''`` gives a link
    relative to the UI's page, for descriptions."""
    prefix = f"{base.rstrip('/')}/" if base else ""
    return f"{prefix}#/experiments/{experiment_id}/runs/{run_id}/artifacts/{quote(path)}?{WORKFLOW_QUERY}"


def ui_command(tracking_uri: str, ui_url: str | None = None) -> str | None:
    """The command that serves the UI on a local store (None for a tracking server, which serves its own UI),
    with ``--port`` when the UI's address (:func:`ui_base_url`) is a local one on another port than 5000."""
    if is_server_uri(tracking_uri):
        return None
    command = f"mlflow ui --backend-store-uri {tracking_uri}"
    address = urlsplit(ui_base_url(tracking_uri, ui_url))
    if address.hostname in ("127.0.0.1", "localhost") and address.port not in (None, 5000):
        command += f" --port {address.port}"
    return command


def ui_lines(tracking_uri: str, experiment_id: str | None = None, run_id: str | None = None,
             ui_url: str | None = None) -> list[str]:
    """How to open the UI: the ``mlflow ui`` command (local stores) and the run's and experiment's URLs."""
    base = ui_base_url(tracking_uri, ui_url)
    command = ui_command(tracking_uri, ui_url)
    lines = [f"open the MLflow UI on it with:  {command}" if command else f"open the MLflow UI on it at:  {base}"]
    if experiment_id is not None:
        if run_id is not None:
            lines.append(f"  this run:          {run_url(base, experiment_id, run_id)}")
        lines.append(f"  experiment's runs: {experiment_url(base, experiment_id)}")
    return lines


# -- experiments ------------------------------------------------------------------------------------------------
def _scale_note() -> str:
    return "any scale: append `scale=tiny|cpu|quickstart|paper` (the runs carry `tags.scale`)"


def experiment_description(name: str, cfg: DictConfig | None = None) -> str:
    """What a SPADE experiment holds, which paper table it reproduces and the commands that regenerate it."""
    from spade.experiments.tables import METRICS, TABLES

    columns = ", ".join(f"`{m.mlflow_key}`" for m in METRICS.values())
    table = next((t for t in TABLES.values() if t.experiment == name), None)
    if table is not None:
        return (
            f"Reproduces **{table.title}** of the SPADE paper (AAMAS 2026). One run per row, named after the "
            f"row: {', '.join(table.rows)}. Every row logs {columns}, so the runs table with those columns is "
            f"the paper's table.\n\n"
            f"Regenerate: `python -m spade.train +experiment={table.composition}` ({_scale_note()}); one row: "
            f"`python -m spade.train +experiment=ROW`. Print the table in the paper's layout: "
            f"`python -m spade.report table={table.key}`."
        )
    if name == "quickstart":
        return (
            "The README's first command (`make quickstart`, i.e. `python -m spade.train +experiment=quickstart`): "
            "a small Cond-DBC student trained on L-shape demonstrations with a tiny conditional expert's guidance, "
            "tested next to the same student untrained and the classical baselines. Not a paper table; it shows "
            "the whole pipeline in about half an hour on a CPU. Regenerate: `make quickstart`."
        )
    if name == "smoke":
        return (
            "Pipeline check (`python -m spade.train +experiment=smoke`, seconds at `scale=tiny`): data "
            "generation, a tiny conditional expert (registered) and a few steps of a Cond-DBC student. Its "
            "figures mean nothing; it reproduces no paper table. Regenerate: `python -m spade.train +experiment=smoke`."
        )
    if name == "evaluation":
        return (
            "Checkpoints tested on a data config's test set by `python -m spade.evaluate ckpt_path=PATH "
            "[data=lshape|ushape|transfer] [scale=...]`; one run per evaluation. Reproduces no table by itself: "
            f"it re-tests students and experts of the tables' rows. Columns: {columns}."
        )
    if name.startswith("sweep_"):
        search = name[len("sweep_"):]
        return (
            f"Optuna search `{search}` (sweeps/search/{search}.yaml): each trial is one run, its lambda in "
            f"`tags.lambda`. Supports Table 1's Cond-DBC rows (the guidance weight); it is not a paper table. "
            f"Regenerate: `python -m spade.train --config-dir sweeps +search={search}` ({_scale_note()})."
        )
    return (
        f"Runs of `python -m spade.train` with `tags.table={name}`; not one of the paper's tables. Each run's "
        f"description gives the command that regenerates it, and its composed config is the artifact "
        f"`config/train.yaml`."
    )


def ensure_experiment_tags(client: Any, experiment: Any, cfg: DictConfig | None = None) -> None:
    """Tag ``experiment`` as model training, store SPADE's runs view (:func:`runs_view_state`) and add the
    description where there is none (a description a person wrote in the UI is kept)."""
    tags = dict(experiment.tags or {})
    if tags.get(KIND_TAG) != KIND_TRAINING:
        client.set_experiment_tag(experiment.experiment_id, KIND_TAG, KIND_TRAINING)
    if not tags.get(NOTE_TAG):
        client.set_experiment_tag(experiment.experiment_id, NOTE_TAG, experiment_description(experiment.name, cfg))
    view = runs_view_state()
    if tags.get(VIEW_TAG) != view:
        client.set_experiment_tag(experiment.experiment_id, VIEW_TAG, view)


def bind_experiment(ml: MLFlowLogger, cfg: DictConfig | None = None) -> None:
    """Find or create the logger's MLflow experiment before the logger does, safely under parallel jobs, and tag it.

    Lightning's ``MLFlowLogger`` looks its experiment up and creates it when absent: two jobs of a sweep that
    start together into an empty store both find it absent and the second ``create_experiment`` fails. Here a
    failed create falls back to the lookup. The experiment gets :func:`ensure_experiment_tags` (also one created
    before SPADE tagged experiments). A resumed run's experiment is tagged the same way.
    """
    from mlflow.exceptions import MlflowException

    client, name = ml._mlflow_client, ml._experiment_name
    if ml._initialized or ml._run_id is not None or ml._experiment_id is not None:
        experiment_id = ml._experiment_id
        if experiment_id is None and ml._run_id is not None:
            experiment_id = client.get_run(ml._run_id).info.experiment_id
        if experiment_id is not None:
            ensure_experiment_tags(client, client.get_experiment(experiment_id), cfg)
        return  # resuming a run, or already bound
    found = client.get_experiment_by_name(name)
    if found is not None:
        if found.lifecycle_stage != "deleted":
            ml._experiment_id = found.experiment_id
            ensure_experiment_tags(client, found, cfg)
        return  # a deleted experiment: Lightning's own handling applies
    try:
        experiment_id = client.create_experiment(
            name, artifact_location=ml._artifact_location,
            tags={KIND_TAG: KIND_TRAINING, NOTE_TAG: experiment_description(name, cfg), VIEW_TAG: runs_view_state()},
        )
    except MlflowException:
        found = client.get_experiment_by_name(name)  # created meanwhile by a parallel job
        if found is None:
            raise
        experiment_id = found.experiment_id
        ensure_experiment_tags(client, found, cfg)
    ml._experiment_id = experiment_id


# -- datasets as run inputs -------------------------------------------------------------------------------------
def dataset_profile(root: str | Path, instances_used: int | None = None) -> dict[str, Any]:
    """The manifest's key facts, as shown in the MLflow UI's dataset panel."""
    raw = read_manifest_json(root)
    labels = raw.get("labels") or {}
    generator = raw.get("generator") or {}

    def values(key: str) -> list[str]:
        entry = labels.get(key) or {}
        return [str(v) for v in entry.get("values", [])] if isinstance(entry, dict) else []

    profile: dict[str, Any] = {
        "instances": raw.get("num_instances"),
        "image_size_px": raw.get("image_size"),
        "resolution_m_per_px": raw.get("resolution"),
        "shapes": values("shape"),
        "maps": values("map_id"),
        "scenarios": len(values("scenario_id")),
        "format_version": raw.get("format_version"),
    }
    if instances_used is not None:
        profile["instances_used"] = int(instances_used)
    frame = raw.get("frame")
    if isinstance(frame, dict) and frame.get("kind"):
        profile["frame"] = frame.get("kind")
    for key in ("preset", "shape", "split", "seed"):
        if generator.get(key) is not None:
            profile[f"generator_{key}"] = generator[key]
    return {k: v for k, v in profile.items() if v not in (None, [], "")}


def _mlflow_dataset(root: Path, name: str, instances_used: int | None) -> Any:
    """An ``mlflow.data`` meta dataset (metadata only: the arrays stay in ``root``) with a profile."""
    from mlflow.data.meta_dataset import MetaDataset

    class SpadeDataset(MetaDataset):
        def __init__(self, source: Any, name: str, digest: str, profile: dict[str, Any]) -> None:
            self._profile = profile
            super().__init__(source=source, name=name, digest=digest)

        @property
        def profile(self) -> dict[str, Any]:
            return self._profile

        def to_dict(self) -> dict[str, str]:
            return {**super().to_dict(), "profile": json.dumps(self._profile, sort_keys=True)}

    from mlflow.data.dataset_source_registry import get_registered_sources, resolve_dataset_source

    # MLflow registers its local-directory source (source type "local") twice; take the first, else resolve.
    local = [c for c in get_registered_sources() if c._get_source_type() == "local"]
    source = local[0](str(root)) if local else resolve_dataset_source(str(root))
    return SpadeDataset(source, name, dataset_fingerprint(root), dataset_profile(root, instances_used))


@dataclass(frozen=True)
class DatasetUse:
    """One dataset input of a run: the directory, the name shown, the context and how many instances were used."""

    root: Path
    name: str
    context: str  # training | validation | test
    instances: int | None = None


def dataset_name(root: Path, split: str | None = None) -> str:
    """``<scale>/<dataset>`` (the data dir's layout), with the split when train and validation share a directory."""
    name = f"{root.parent.name}/{root.name}" if root.parent.name else root.name
    return f"{name} ({split} split)" if split else name


def dataset_uses(datamodule: Any) -> list[DatasetUse]:
    """The datasets a ``PathDataModule`` trained, validated and tested on (only what it set up)."""
    uses: list[DatasetUse] = []
    train_dir = getattr(datamodule, "train_dir", None)
    test_dir = getattr(datamodule, "test_dir", None)
    train_set, val_set = getattr(datamodule, "train_set", None), getattr(datamodule, "val_set", None)
    test_set = getattr(datamodule, "test_set", None)
    if train_dir is not None and (Path(train_dir) / "manifest.json").is_file():
        root = Path(train_dir)
        if train_set is not None:
            uses.append(DatasetUse(root, dataset_name(root, "train"), "training", len(train_set)))
        if val_set is not None and len(val_set):
            uses.append(DatasetUse(root, dataset_name(root, "validation"), "validation", len(val_set)))
    if test_set is not None:
        if test_dir is not None and (Path(test_dir) / "manifest.json").is_file():
            uses.append(DatasetUse(Path(test_dir), dataset_name(Path(test_dir)), "test", len(test_set)))
        elif test_set is val_set and train_dir is not None and val_set is not None:
            root = Path(train_dir)  # no held-out test set: the validation split stands in
            uses.append(DatasetUse(root, dataset_name(root, "validation, as test"), "test", len(val_set)))
    return uses


def log_dataset_inputs(client: Any, run_id: str, uses: list[DatasetUse]) -> None:
    """Log ``uses`` as the run's dataset inputs (the MLflow UI's Dataset column and the run page's datasets)."""
    from mlflow.entities import DatasetInput, InputTag
    from mlflow.utils.mlflow_tags import MLFLOW_DATASET_CONTEXT

    inputs = [
        DatasetInput(_mlflow_dataset(use.root, use.name, use.instances)._to_mlflow_entity(),
                     tags=[InputTag(MLFLOW_DATASET_CONTEXT, use.context)])
        for use in uses
    ]
    if inputs:
        client.log_inputs(run_id, datasets=inputs)


# -- a run's description ----------------------------------------------------------------------------------------
FIGURES = ("ape_cm", "fid", "hd19", "failure_rate", "over_20cm_rate", "planner/ape_cm", "planner/over_20cm_rate")  # the test figures a description shows, in this order


def _fmt(key: str, value: float | None) -> str:
    from spade.experiments.tables import METRICS

    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "n/a"
    if key.endswith("_cm"):  # a description's figures to what they mean: a tenth of a centimetre (the tables keep .2f)
        return f"{value:.1f}"
    metric = METRICS.get(key) or METRICS.get(key.replace("/", "_"))  # "planner/ape_cm" -> planner_ape_cm
    return metric.format(value) if metric else f"{value:.4g}"


def figure_rows(metrics: dict[str, float]) -> list[tuple[str, dict[str, float]]]:
    """(label, {figure: value}) for the run's test figures, each classical baseline (``test/baseline/<name>/``)
    and the untrained model (``untrained/``), in that order; only those the run logged."""
    rows: list[tuple[str, dict[str, float]]] = []
    own = {k: metrics[f"test/{k}"] for k in FIGURES if f"test/{k}" in metrics}
    if own:
        rows.append(("this model", own))
    baselines: dict[str, dict[str, float]] = {}
    for key, value in metrics.items():
        match = re.fullmatch(r"test/baseline/([^/]+)/(.+)", key)
        if match and match.group(2) in FIGURES:
            baselines.setdefault(match.group(1), {})[match.group(2)] = value
    rows += [(f"baseline: {name}", figs) for name, figs in sorted(baselines.items())]
    untrained = {k: metrics[f"untrained/{k}"] for k in FIGURES if f"untrained/{k}" in metrics}
    if untrained:
        rows.append(("untrained", untrained))
    return rows


def figures_table(metrics: dict[str, float]) -> str:
    """The test figures next to the baselines as a markdown table ('' when the run has no test figures)."""
    from spade.experiments.tables import METRICS

    rows = figure_rows(metrics)
    if not rows:
        return ""
    by_key = {m.mlflow_key.split("/", 1)[1]: m for m in METRICS.values() if m.mlflow_key.startswith("test/")}
    labels = {k: by_key[k].label if k in by_key else k.replace("_", " ") for k in FIGURES}
    lines = ["| test set | " + " | ".join(labels[k] for k in FIGURES) + " |", "|---" * (len(FIGURES) + 1) + "|"]
    for label, figs in rows:
        name = f"**{label}**" if label == "this model" else label
        lines.append(f"| {name} | " + " | ".join(_fmt(k, figs.get(k)) for k in FIGURES) + " |")
    return "\n".join(lines)


@dataclass(frozen=True)
class PrerequisiteUse:
    """A model a run was built on: the ``requires`` entry, its checkpoint, and where it was registered."""

    key: str
    experiment: str
    checkpoint: str
    registered: str | None = None  # "<name> v<version>"
    run_link: str | None = None  # markdown link to the run that trained it


def prerequisite_uses(cfg: DictConfig, client: Any | None) -> list[PrerequisiteUse]:
    """The run's prerequisites as resolved: registry-cache checkpoints are traced back to their runs."""
    out = []
    cache = Path(str(OmegaConf.select(cfg, "paths.registry_cache_dir", default="") or "")).resolve()
    for key, req in (cfg.get("requires") or {}).items():
        ckpt = OmegaConf.select(cfg, str(req.target), default=None)
        if ckpt in (None, "", "???"):
            continue
        registered = link = None
        try:
            parts = Path(str(ckpt)).resolve().relative_to(cache).parts
        except ValueError:
            parts = ()  # an explicit checkpoint path, not from the registry
        if client is not None and len(parts) >= 2 and re.fullmatch(r"v\d+", parts[1]):
            name, version = parts[0], parts[1][1:]
            registered = f"{name} v{version}"
            try:
                mv = client.get_model_version(name, version)
                run = client.get_run(mv.run_id)
                link = f"[{run.info.run_name}]({relative_run_link(run.info.experiment_id, mv.run_id)})"
            except Exception as exc:  # noqa: BLE001 - a description must not fail a finished run
                log.warning("prerequisite %s: no run found for %s (%s)", key, registered, exc)
        out.append(PrerequisiteUse(str(key), str(req.experiment), str(ckpt), registered, link))
    return out


def relative_run_link(experiment_id: str, run_id: str) -> str:
    """A link that works inside the MLflow UI whatever its address (its routes live in the URL's fragment)."""
    return f"#/experiments/{experiment_id}/runs/{run_id}?{WORKFLOW_QUERY}"


def regenerate_command(cfg: DictConfig) -> str | None:
    """The command that makes this run again: the row's experiment at its scale, else the entry point
    (``task_name``: train, evaluate) with the command line's overrides."""
    run_name = str(cfg.get("run_name") or "")
    scale = OmegaConf.select(cfg, "scale.name", default=None)
    if run_name and (REPO_CONF / "experiment" / f"{run_name}.yaml").is_file():
        return f"python -m spade.train +experiment={run_name}" + (f" scale={scale}" if scale else "")
    from hydra.core.hydra_config import HydraConfig

    if HydraConfig.initialized():
        overrides = list(HydraConfig.get().overrides.task)
        return " ".join([f"python -m spade.{cfg.get('task_name') or 'train'}", *overrides])  # train, evaluate
    return None


def _what(tags: dict[str, Any]) -> str:
    """``Cond-DBC student``, ``Cond-expert`` (the role is left out when the approach already names it)."""
    approach, role = str(tags.get("approach") or ""), str(tags.get("role") or "")
    if role and role.lower() not in approach.lower():
        return f"{approach} {role}".strip()
    return approach or role or "model"


def run_description(cfg: DictConfig, metrics: dict[str, float], uses: list[DatasetUse],
                    prerequisites: list[PrerequisiteUse], pictures: list[str] | None = None,
                    run: tuple[str, str] | None = None) -> str:
    """A run's one-paragraph summary (markdown): row, approach, data, prerequisites, test figures and baselines."""
    tags = dict(cfg.get("tags") or {})
    row = cfg.get("run_name") or tags.get("row") or "run"
    what = _what(tags)
    details = [f"size {tags['size']}" if tags.get("size") else None,
               f"{_fmt('params', metrics['model/params'])} parameters" if "model/params" in metrics else None]
    details_text = ", ".join(d for d in details if d)
    sentence = f"**{row}**: {what or 'model'}" + (f" ({details_text})" if details_text else "")
    if tags.get("shape"):
        sentence += f", {tags['shape']}-shape paths"
    if tags.get("scale"):
        sentence += f", scale `{tags['scale']}`"
    sentence += f"; experiment `{tags.get('table', 'none')}`."
    parts = [sentence]
    train = [u for u in uses if u.context == "training"]
    val = [u for u in uses if u.context == "validation"]
    test = [u for u in uses if u.context == "test"]

    def n(use: DatasetUse) -> str:
        return f"{use.instances} instances" if use.instances is not None else "all instances"

    if train:
        extra = f", validated on {n(val[0])} of its held-out scenarios" if val else ""
        parts.append(f"Trained on `{train[0].name.split(' (')[0]}` ({n(train[0])}{extra}).")
    if test:
        parts.append(f"Tested on `{test[0].name}` ({n(test[0])}).")
    if prerequisites:
        items = []
        for p in prerequisites:
            item = f"{p.key} from `{p.experiment}`"
            if p.registered:
                item += f" (registered model `{p.registered}`" + (f", run {p.run_link})" if p.run_link else ")")
            else:
                item += f" (checkpoint `{p.checkpoint}`)"
            items.append(item)
        parts.append("Prerequisites: " + "; ".join(items) + ".")
    command = regenerate_command(cfg)
    if command:
        parts.append(f"Regenerate: `{command}`.")
    text = " ".join(parts)
    table = figures_table(metrics)
    text += ("\n\n" + table) if table else "\n\nNo test figures (the run was not tested)."
    if pictures:
        shown = [f"[{p}]({artifact_url('', *run, p)})" if run else f"`{p}`" for p in pictures]
        text += "\n\nPictures (Artifacts tab): " + ", ".join(shown) + "."
    return text


def _picture_paths(client: Any, run_id: str) -> list[str]:
    try:
        return sorted(a.path for a in client.list_artifacts(run_id, "predictions") if a.path.endswith(".png"))
    except Exception:  # noqa: BLE001 - listing artifacts is a nicety of the description
        return []


# -- run start and end ------------------------------------------------------------------------------------------
@rank_zero_only  # under DDP, other ranks' MLflow loggers hold no run (their experiment is a no-op)
def start_run_logging(cfg: DictConfig, model: L.LightningModule, loggers: list[Logger]) -> None:
    """Log the composed config (flattened params and a YAML artifact) and the FID extractor's identity."""
    ml = mlflow_logger(loggers)
    if ml is None:
        return
    bind_experiment(ml, cfg)
    resolved = OmegaConf.to_container(cfg, resolve=True)
    params = {f"cfg/{k}": v for k, v in flatten(resolved).items() if not k.startswith("hydra")}
    fid = getattr(getattr(model, "test_metrics", None), "fid_identity", None)
    if fid:
        params["fid/extractor_identity"] = fid
    # A resumed run continues an MLflow run whose params are immutable: log only what it lacks (ckpt_path and
    # anything else set differently for the resume is recorded as a tag instead).
    existing = ml.experiment.get_run(ml.run_id).data.params
    if existing:
        changed = {k: v for k, v in params.items() if k in existing and existing[k] != str(v)}
        for key, value in changed.items():
            ml.experiment.set_tag(ml.run_id, f"resumed/{key}", str(value))
        params = {k: v for k, v in params.items() if k not in existing}
    if params:
        ml.log_hyperparams(params)
    ml.experiment.log_text(ml.run_id, OmegaConf.to_yaml(cfg, resolve=True), "config/train.yaml")
    if fid:
        ml.experiment.set_tag(ml.run_id, "fid_extractor", fid)


@dataclass(frozen=True)
class RunRef:
    """Where a finished run lives, for the closing lines of ``spade.train``."""

    tracking_uri: str
    experiment_id: str
    run_id: str
    run_name: str


_last_run: RunRef | None = None


def last_run() -> RunRef | None:
    """The run most recently finished by :func:`finish_run` in this process (a row after its prerequisites)."""
    return _last_run


def describe_run(cfg: DictConfig, ml: MLFlowLogger, datamodule: Any, contexts: tuple[str, ...] | None = None
                 ) -> tuple[list[DatasetUse], dict[str, float]]:
    """Log the run's dataset inputs and set its description; returns (dataset uses, the run's metrics)."""
    client, run_id = ml.experiment, ml.run_id
    uses = dataset_uses(datamodule) if datamodule is not None else []
    if contexts is not None:
        uses = [u for u in uses if u.context in contexts]
    try:
        log_dataset_inputs(client, run_id, uses)
    except (OSError, ValueError) as exc:  # an unreadable manifest: the run itself is fine, say so
        log.warning("datasets not logged as MLflow inputs: %s", exc)
    run = client.get_run(run_id)
    metrics = dict(run.data.metrics)
    description = run_description(cfg, metrics, uses, prerequisite_uses(cfg, client), _picture_paths(client, run_id),
                                  (str(run.info.experiment_id), run_id))
    client.set_tag(run_id, NOTE_TAG, description)
    global _last_run
    _last_run = RunRef(str(ml._tracking_uri), str(run.info.experiment_id), run_id, str(run.info.run_name))
    return uses, metrics


@rank_zero_only
def finish_run(cfg: DictConfig, trainer: L.Trainer, model: L.LightningModule, loggers: list[Logger]) -> None:
    """Log the checkpoints, the datasets as inputs and the run's description; register the model when asked."""
    ml = mlflow_logger(loggers)
    if ml is None:
        return
    ckpt_cb = trainer.checkpoint_callback
    paths = {}
    if ckpt_cb is not None:
        if ckpt_cb.best_model_path:
            paths["best"] = ckpt_cb.best_model_path
        if getattr(ckpt_cb, "last_model_path", ""):
            paths["last"] = ckpt_cb.last_model_path
    for kind, path in paths.items():
        ml.experiment.log_artifact(ml.run_id, path, artifact_path=f"checkpoints/{kind}")
    uses, metrics = describe_run(cfg, ml, getattr(trainer, "datamodule", None))
    from spade.experiments.registry import data_fingerprint, register_checkpoint, registry_name

    name = registry_name(cfg)
    if name and paths:
        tags = {**dict(cfg.get("tags") or {}), **dict((cfg.get("registry") or {}).get("tags") or {})}
        register_checkpoint(ml, name, f"checkpoints/{'best' if 'best' in paths else 'last'}", tags=tags,
                            data_fingerprint=data_fingerprint(cfg), description=model_description(cfg, uses),
                            version_description=version_description(cfg, ml, metrics))


@rank_zero_only
def finish_evaluation(cfg: DictConfig, trainer: L.Trainer, loggers: list[Logger]) -> None:
    """``spade.evaluate``'s run: the test dataset as input and a description with the figures and baselines."""
    ml = mlflow_logger(loggers)
    if ml is None:
        return
    bind_experiment(ml, cfg)
    describe_run(cfg, ml, getattr(trainer, "datamodule", None), contexts=("test",))


def model_description(cfg: DictConfig, uses: list[DatasetUse]) -> str:
    """A registered model's description: what it is, what trained it, on which data."""
    from spade.experiments.registry import data_fingerprint

    tags = dict(cfg.get("tags") or {})
    what = _what(tags)
    text = (f"SPADE {what}, size `{tags.get('size', '?')}`, for {tags.get('shape', '?')}-shape paths at scale "
            f"`{tags.get('scale', '?')}`, trained by row `{cfg.get('run_name')}` (experiment "
            f"`{tags.get('table', 'none')}`). The name ends in the fingerprint of its training data "
            f"(`{data_fingerprint(cfg)}`, tag `data_fingerprint`): rows that require this model find it by that "
            f"name. Each version links to the run that trained it.")
    train = next((u for u in uses if u.context == "training"), None)
    if train is not None:
        text += f" Training data: `{train.name.split(' (')[0]}` (dataset digest `{dataset_fingerprint(train.root)}`)."
    command = regenerate_command(cfg)
    if command:
        text += f" Retrain: `{command}`."
    return text


def version_description(cfg: DictConfig, ml: MLFlowLogger, metrics: dict[str, float]) -> str:
    run = ml.experiment.get_run(ml.run_id)
    figures = ", ".join(f"{k} {_fmt(k, metrics[f'test/{k}'])}" for k in FIGURES if f"test/{k}" in metrics)
    link = f"[{run.info.run_name}]({relative_run_link(run.info.experiment_id, ml.run_id)})"
    return f"From run {link}" + (f"; test: {figures}." if figures else " (not tested).")


# -- the closing lines of spade.train ---------------------------------------------------------------------------
def _find_run(cfg: DictConfig) -> RunRef | None:
    """The run of ``cfg`` in its store: the one this process finished, else the latest with its name."""
    ref = last_run()
    if ref is not None and ref.run_name == str(cfg.get("run_name")):
        return ref
    if OmegaConf.select(cfg, "logger.mlflow", default=None) is None:
        return None
    from mlflow import MlflowClient

    uri = str(cfg.paths.mlflow_tracking_uri)
    client = MlflowClient(tracking_uri=uri)
    experiment = client.get_experiment_by_name(str(OmegaConf.select(cfg, "logger.mlflow.experiment_name")))
    if experiment is None:
        return None
    runs = client.search_runs([experiment.experiment_id], filter_string=f"attributes.run_name = '{cfg.run_name}'",
                              order_by=["attributes.start_time DESC"], max_results=1)
    return RunRef(uri, experiment.experiment_id, runs[0].info.run_id, runs[0].info.run_name) if runs else None


def run_summary(cfg: DictConfig, metrics: dict[str, Any]) -> str:
    """The closing lines: test metrics next to the baselines, the ``mlflow ui`` command and URLs to the run and
    to its experiment's runs table."""
    lines = [f"run {cfg.get('run_name')} finished"]
    if (cfg.get("scale") or {}).get("name") == "tiny":  # issue 24: tiny figures are never read as results
        from spade.experiments.tables import TINY_NOTICE

        lines.append(f"  {TINY_NOTICE}")
    keys = ("ape_cm", "fid", "hd19", "failure_rate", "over_20cm_rate", "planner/ape_cm", "planner/over_20cm_rate",
            "planner/low_confidence_rate", "seconds_per_sample")
    prefixes = ["test", *sorted({"/".join(k.split("/")[:3]) for k in metrics if k.startswith("test/baseline/")}),
                "untrained"]
    for prefix in prefixes:
        vals = [f"{k}={metrics[f'{prefix}/{k}']:.4g}" for k in keys if f"{prefix}/{k}" in metrics]
        if vals:
            label = prefix.replace("test/baseline/", "baseline ")
            lines.append(f"  {label:17s}: " + "  ".join(vals))
    uri = str(cfg.paths.mlflow_tracking_uri)
    try:
        ref = _find_run(cfg)
    except Exception as exc:  # noqa: BLE001 - the closing lines must not fail a finished run
        log.warning("could not look the run up in %s: %s", uri, exc)
        ref = None
    lines += ui_lines(uri, ref.experiment_id if ref else None, ref.run_id if ref else None)
    return "\n".join(lines)


# -- spade.report ---------------------------------------------------------------------------------------------
def publish_report(table: Any, results: dict[str, Any], tracking_uri: str, files: dict[str, Path],
                   log_to_runs: bool = True) -> list[str]:
    """After ``spade.report`` wrote a table: tag its experiment (:func:`ensure_experiment_tags`), log the chart and
    the markdown into each shown row's run (``report/<table>.png``, ``report/<table>.md``: the run page's
    Artifacts tab) and return the lines that open the table in the MLflow UI."""
    from mlflow import MlflowClient

    client = MlflowClient(tracking_uri=tracking_uri)
    experiment = client.get_experiment_by_name(table.experiment)
    if experiment is None:
        return []
    ensure_experiment_tags(client, experiment)
    logged = 0
    if log_to_runs and files.get("png"):
        for result in results.values():
            # Only SPADE training runs (they all hold config/train.yaml), never runs made by other tools.
            if result.run_id and client.list_artifacts(result.run_id, "config"):
                for key in ("png", "markdown"):
                    if files.get(key):
                        client.log_artifact(result.run_id, str(files[key]), artifact_path="report")
                logged += 1
    base = ui_base_url(tracking_uri)
    command = ui_command(tracking_uri)
    lines = ["MLflow UI" + (f" (`{command}`)" if command else "") + ":",
             f"- runs of `{table.experiment}`: {experiment_url(base, experiment.experiment_id)}"]
    lines += [f"- {row}: {run_url(base, experiment.experiment_id, r.run_id)}" for row, r in results.items() if r.run_id]
    if logged:
        lines.append(f"- the chart is in each of those {logged} runs as `report/{table.key}.png` (Artifacts tab)")
    return lines
