"""A run's datasets as MLflow dataset inputs: name, digest (the dataset's fingerprint), source, context, profile.

Each dataset a run trained, validated or tested on (:func:`dataset_uses`) is logged as an ``mlflow.data`` input
(:func:`log_dataset_inputs`): name ``<scale>/<dataset>`` (with the split when training and validation share a
directory), digest = the dataset's fingerprint, source = its directory, context training / validation / test,
and the manifest's key facts as the profile (:func:`dataset_profile`) that the MLflow UI's dataset panel shows.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from spade.data.fingerprint import dataset_fingerprint
from spade.data.format import read_manifest_json


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

    import warnings

    from mlflow.data.dataset_source_registry import resolve_dataset_source
    from mlflow.data.filesystem_dataset_source import FileSystemDatasetSource

    with warnings.catch_warnings():
        # MLflow registers its local-directory source twice (URI schemes "" and "file"), so resolving a local path
        # warns that it "can be interpreted in multiple ways": both readings are the same source type, "local".
        warnings.filterwarnings("ignore", message="The specified dataset source can be interpreted in multiple ways")
        source = resolve_dataset_source(str(root), candidate_sources=[FileSystemDatasetSource])
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
        _log_inputs(client, run_id, inputs)


def _log_inputs(client: Any, run_id: str, inputs: list[Any], attempts: int = 3) -> None:
    """``client.log_inputs``, safely when a parallel job logs the same dataset into the experiment at that moment.

    MLflow's SQL store keeps one ``datasets`` row per experiment, name and digest and writes it as
    look-up-then-insert: two jobs of a sweep that test on the same set and finish together both find it absent
    and the second insert fails on the unique key (``IntegrityError``; a ``RestException`` through
    ``mlflow server``). The failed write is one transaction, rolled back whole; the row exists now, so the same
    call again links this run to it. Any other failure, or the same one ``attempts`` times, raises.
    """
    import random
    import time

    from mlflow.exceptions import MlflowException

    for attempt in range(attempts):
        try:
            client.log_inputs(run_id, datasets=inputs)
            return
        except MlflowException as error:
            if "UNIQUE constraint" not in str(error) or attempt == attempts - 1:
                raise
            time.sleep(random.uniform(0.05, 0.3))
