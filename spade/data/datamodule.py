"""``PathDataModule``: train/validation split by scenario, a held-out test dataset, the robot-frame mirror
augmentation and the (optionally widened) path target."""

from __future__ import annotations

import logging
import math
from dataclasses import fields
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
from lightning.pytorch.overrides.distributed import UnrepeatedDistributedSampler
from torch.utils.data import DataLoader, Subset

from spade.data import DatasetError, read_manifest
from spade.data.path_dataset import PathDataset
from spade.data.augment import augment_batch, check_augmentation, widen_path
from spade.data.checks import check_dataset, split_pair_problems
from spade.data.datamodule_options import DataOptions
from spade.utils.errors import ConfigError
from spade.data.settings import Generator
from spade.data.labelled import StateView
from spade.data.plausible import ceiling_map, plausible_images
from spade.data.writer import DatasetExistsError

log = logging.getLogger(__name__)


def split_by_scenario(scenario_ids: list[str], val_fraction: float, seed: int) -> tuple[list[int], list[int]]:
    """Indices of (train, validation) with whole scenarios on one side: instances of a scenario are near-duplicates."""
    if not 0.0 <= val_fraction < 1.0:
        raise ValueError(f"data.val_fraction must be in [0, 1), got {val_fraction}")
    scenarios = sorted(set(scenario_ids))
    if val_fraction == 0.0 or len(scenarios) < 2:
        return list(range(len(scenario_ids))), []
    order = np.random.default_rng(seed).permutation(len(scenarios))
    n_val = min(len(scenarios) - 1, max(1, math.ceil(val_fraction * len(scenarios))))
    val_set = {scenarios[i] for i in order[:n_val]}
    train = [i for i, s in enumerate(scenario_ids) if s not in val_set]
    val = [i for i, s in enumerate(scenario_ids) if s in val_set]
    return train, val


def leaked_scenarios(train: PathDataset, test: PathDataset, share: float = 0.5) -> list[str]:
    """The test scenarios more than ``share`` of whose windows are identical (by content:
    :meth:`PathDataset.instance_digests`) to training windows."""
    seen = set(train.instance_digests())
    ids = test.labels("scenario_id")
    total: dict[str, int] = {}
    same: dict[str, int] = {}
    for scenario, digest in zip(ids, test.instance_digests()):
        total[scenario] = total.get(scenario, 0) + 1
        same[scenario] = same.get(scenario, 0) + (digest in seen)
    return sorted(s for s, n in total.items() if same[s] > share * n)


class PathDataModule(L.LightningDataModule):
    """Datasets of the annotation tool as Lightning data.

    ``train_dir`` is split into train and validation by scenario; ``test_dir`` (a held-out map) is the test set
    (the validation split stands in when it is None). ``train_generate`` / ``test_generate`` are annotation
    configs: ``prepare_data`` builds a missing dataset with them, so a fresh machine needs no manual step.
    ``generator`` builds it: ``generator(dataset directory, *_generate entry)``; the data configs give the
    annotation tool's (``conf/data/generator/annotate.yaml``: :func:`spade.annotation.run.generate_dataset`).
    ``experiment`` is not the data module's: ``conf/data/own.yaml`` names there the MLflow experiment of runs on a
    user's own datasets (read by ``conf/logger/mlflow.yaml``), so it is accepted and kept, never used here.
    The loader options are checked by :class:`~spade.data.datamodule_options.DataOptions`, the same checks as
    ``spade.train``'s preflight.
    """

    def __init__(
        self,
        train_dir: str | Path | None,
        test_dir: str | Path | None = None,
        train_generate: Any = None,
        test_generate: Any = None,
        pin_memory: bool = False,
        persistent_workers: bool = False,
        augment: str | bool | None = "none",
        test_shape: str | None = None,
        generator: Generator | None = None,
        experiment: str | None = None,
        unlabelled_dir: str | Path | None = None,
        unlabelled_generate: Any = None,
        unlabelled_labels: bool = False,
        unlabelled_teacher: str | Path | None = None,
        **loader_options: Any,
    ) -> None:
        unknown = sorted(set(loader_options) - {f.name for f in fields(DataOptions)})
        if unknown:
            raise ConfigError(f"data.{unknown[0]} is not an option of the data module; its options are the "
                              f"arguments of PathDataModule and the fields of DataOptions "
                              f"(spade/data/datamodule_options.py): remove it or add it there")
        options = DataOptions(**loader_options)
        self.options = options  # every loader option, typed and checked: a new one is a DataOptions field
        super().__init__()
        self.experiment = experiment
        self.encoding = options.encoding
        self.train_dir = Path(train_dir) if train_dir not in (None, "") else None
        self.test_dir = Path(test_dir) if test_dir else None
        self.train_generate, self.test_generate = train_generate, test_generate
        self.val_fraction, self.split_seed = options.val_fraction, options.split_seed
        self.batch_size = options.batch_size
        self.eval_batch_size = options.eval_batch_size or options.batch_size
        self.num_workers, self.pin_memory = options.num_workers, pin_memory
        self.persistent_workers = persistent_workers and options.num_workers > 0
        self.augment = check_augmentation(augment)
        self.target_width_px = options.target_width_px
        self.max_train_instances, self.max_test_instances = options.max_train_instances, options.max_test_instances
        self.test_shape = test_shape
        self.target_source = options.target_source
        self.unlabelled_dir = Path(unlabelled_dir) if unlabelled_dir not in (None, "") else None
        self.unlabelled_generate = unlabelled_generate
        self.max_unlabelled_instances = options.max_unlabelled_instances
        # True: the unlabelled states keep their generator draw as a BC label (the oracle teacher's own samples as
        # labels: diffusion-based augmentation read literally, with a perfect teacher)
        self.unlabelled_labels = bool(unlabelled_labels)
        # an expert checkpoint: the labels are its committed plans instead (spade.training.teacher_labels)
        self.unlabelled_teacher = Path(unlabelled_teacher) if unlabelled_teacher not in (None, "") else None
        self.unlabelled_teacher_samples = options.unlabelled_teacher_samples
        self.teacher_labels_dir: Path | None = None
        if self.unlabelled_teacher is not None and not (self.unlabelled_labels and self.unlabelled_dir is not None):
            raise ValueError(f"data.unlabelled_teacher={self.unlabelled_teacher} labels the unlabelled states: set "
                             "data.unlabelled_dir and data.unlabelled_labels=true with it (or drop it)")
        self.generator = generator
        self.train_set = self.val_set = self.test_set = None

    # -- Lightning hooks -------------------------------------------------------------------------------------
    def _testing_only(self) -> bool:
        """Whether the trainer only tests (``spade.evaluate``, an untrained model's test) with a test set of its
        own: then the training set is neither built nor read (a machine that evaluates needs no training data)."""
        if self.test_dir is None or self.trainer is None:
            return False
        from lightning.pytorch.trainer.states import TrainerFn

        return self.trainer.state.fn == TrainerFn.TESTING

    def prepare_data(self) -> None:
        sets = [("data.train_dir", self.train_dir, self.train_generate),
                ("data.test_dir", self.test_dir, self.test_generate)]
        if self.unlabelled_dir is not None:
            sets.append(("data.unlabelled_dir", self.unlabelled_dir, self.unlabelled_generate))
        if self._testing_only():
            sets = sets[1:2]
        for key, root, config in sets:
            check_dataset(root, config, key)  # an existing dataset made with other settings, or not a dataset
            if root is None or (root / "manifest.json").is_file():
                continue
            if config is None:
                raise DatasetError(
                    f"{key}={root}: dataset missing and no generator config given (data=own reads datasets as they "
                    f"are); build it with `python -m spade.annotate out_dir={root}`, or point {key} at an existing "
                    "dataset"
                )
            if self.generator is None:
                raise DatasetError(
                    f"{root}: dataset missing and the data module has no generator to build it; set the data "
                    "config's generator (conf/data/generator/annotate.yaml) or build it with "
                    f"`python -m spade.annotate out_dir={root}`."
                )
            try:
                self.generator(root, config)
            except DatasetExistsError:
                # Another run generated the same missing dataset first (two runs' prepare_data at once): its
                # dataset is kept. It is used only when it was made with these settings; otherwise this refuses it.
                if not (root / "manifest.json").is_file():
                    raise
                check_dataset(root, config, key)

    def setup(self, stage: str | None = None) -> None:
        # A test with a test set of its own reads that set alone: spade.evaluate needs no training data. The
        # training set, when a later stage loads it, is still checked against the test set (size, leaks).
        test_only = stage == "test" and self._testing_only()
        if self.train_set is None and not test_only:
            if self.train_dir is None:
                raise DatasetError("data.train_dir is not set; point it at a training set (data=own "
                                   "data.train_dir=DIR), or give a test set (data.test_dir=DIR) to test alone")
            full = PathDataset(self.train_dir, encoding=self.encoding)
            train, val = split_by_scenario(full.labels("scenario_id"), self.val_fraction, self.split_seed)
            if self.max_train_instances:
                train = train[: self.max_train_instances]
                val = val[: max(1, self.max_train_instances // 4)] if val else val
            train_set, self.val_set = Subset(full, train), Subset(full, val)
            if self.unlabelled_dir is not None:  # set only once whole: a refusal leaves the module unset, not half-set
                train_set = self._with_unlabelled(train_set)
            self.train_set = train_set
            if self.test_set is not None and self.test_dir is not None:  # tested alone first (test_untrained)
                self._check_compatible(self.test_set.dataset)
        if self.test_set is None:
            if self.test_dir is not None:
                test = PathDataset(self.test_dir, encoding=self.encoding)
                if self.train_set is not None:
                    self._check_compatible(test)
                shapes = test.labels("shape")
                idx = [i for i, s in enumerate(shapes) if self.test_shape in (None, s)]
                if not idx:
                    raise DatasetError(
                        f"data.test_shape={self.test_shape!r}: {self.test_dir} holds no test instances of that "
                        f"shape (it holds {', '.join(sorted({str(s) for s in shapes})) or 'none'}); set data.test_shape to one of "
                        "them, or data.test_shape=null for all"
                    )
                idx = idx[: self.max_test_instances or None]
                self.test_set = Subset(test, idx)
                if not test.manifest.alternatives:
                    log.warning(
                        "%s has no alternative demonstrations (made before SPADE drew them, or imported): the "
                        "test leaves floor_cm, ape_over_floor, plausibility_cm and commit_rate out. Delete the folder "
                        "to have it regenerated with them (spade.annotate alternatives.count=32).", self.test_dir)
            else:
                self.test_set = self.val_set

    def teacher_label_request(self) -> tuple[Path, Path, int, int | None, str] | None:
        """(teacher checkpoint, unlabelled states, samples per state, at most how many states, encoding) when the
        unlabelled states take a teacher's plans as labels (``unlabelled_teacher``), else None."""
        if self.unlabelled_teacher is None or self.unlabelled_dir is None:
            return None
        return (self.unlabelled_teacher, self.unlabelled_dir, self.unlabelled_teacher_samples,
                self.max_unlabelled_instances, self.encoding)

    def use_teacher_labels(self, path: str | Path) -> None:
        """The teacher-labelled copy of the unlabelled states to train on (written by the training side)."""
        self.teacher_labels_dir = Path(path)

    def _with_unlabelled(self, labelled: Subset) -> Any:
        """The training set with the states of ``unlabelled_dir`` (their demonstrations never a label: only the
        diffusion margin sees them, :class:`~spade.data.labelled.StateView`), after checking their windows and that
        they share no scenario with the test set."""
        from torch.utils.data import ConcatDataset

        full = labelled.dataset
        unlabelled = PathDataset(self.unlabelled_dir, encoding=self.encoding)
        if unlabelled.image_size != full.image_size or unlabelled.resolution != full.resolution:
            raise DatasetError(f"data.unlabelled_dir={self.unlabelled_dir}: windows of {unlabelled.image_size} at "
                               f"{unlabelled.resolution} m/px, the training set's are {full.image_size} at "
                               f"{full.resolution} m/px; generate it with the training set's window")
        if self.test_dir is not None:
            test = PathDataset(self.test_dir, encoding=self.encoding)
            leaked = leaked_scenarios(unlabelled, test)
            if leaked:
                raise DatasetError(f"data.unlabelled_dir={self.unlabelled_dir}: {len(leaked)} test scenarios "
                                   f"({', '.join(leaked[:5])}) are among its states: the test would grade states "
                                   "the margin trained on; draw the unlabelled states with another seed")
        n = len(unlabelled) if not self.max_unlabelled_instances else min(len(unlabelled),
                                                                          self.max_unlabelled_instances)
        if self.unlabelled_teacher is not None:  # the teacher's medoid plans as the labels, made by the training side
            if self.teacher_labels_dir is None:
                raise DatasetError(f"data.unlabelled_teacher={self.unlabelled_teacher}: its labels are not made yet; "
                                   "spade.train makes them (spade.training.teacher_labels.label_unlabelled(datamodule) "
                                   "before fitting)")
            unlabelled = PathDataset(self.teacher_labels_dir, encoding=self.encoding)
            n = len(unlabelled)
        slots = max(full.manifest.alternatives, unlabelled.manifest.alternatives)
        k = full.manifest.num_waypoints
        self.unlabelled_count = n
        return ConcatDataset([StateView(labelled, True, slots, k),
                              StateView(Subset(unlabelled, list(range(n))), self.unlabelled_labels, slots, k)])

    def _check_compatible(self, test: PathDataset) -> None:
        train = self.val_set.dataset  # the training set's dataset (the split's other part)
        if test.image_size != train.image_size or test.resolution != train.resolution:
            raise DatasetError(
                f"{self.test_dir}: test instances are {test.image_size} at {test.resolution} m/px, training ones "
                f"{train.image_size} at {train.resolution} m/px; regenerate one of them with the other's window"
            )
        # A leak is a test scenario that *is* a training one: most of its windows (same map content, same
        # demonstration, same places) are identical to training windows. Found by content, since scenario ids are
        # per-map counters (site/L000): two datasets made on one map with other seeds or sketches share ids but no
        # scenario. A few identical windows (an open hall's straight stretches) are a coincidence, not a leak.
        # Two parts of one map's split (python -m spade.annotate split=area:train / split=area:test) must be cut on
        # the same line: a test part of another split (another fraction, axis or map version) may overlap training.
        splits = [(d.manifest.extra or {}).get("split") for d in (train, test)]
        if any(s is not None for s in splits):
            problems = split_pair_problems(*splits)
            if problems:
                raise DatasetError(f"{self.test_dir}: not the test part of {self.train_dir}'s split: "
                                   f"{'; '.join(problems)}. Annotate both parts with the same split settings "
                                   "(split=MODE:train and split=MODE:test, the same split_fraction and split_axis)")
        leaked = leaked_scenarios(train, test)
        if leaked:
            shown = ", ".join(leaked[:5]) + (f" and {len(leaked) - 5} more" if len(leaked) > 5 else "")
            raise DatasetError(f"{self.test_dir}: {len(leaked)} test scenarios ({shown}) are training scenarios of "
                               f"{self.train_dir} (most of their windows identical): a leak. Make the test set from "
                               "other demonstrations (another seed, other sketches or another map)")

    def _windows_root(self) -> Path:
        """The dataset whose windows describe this data: the training set's, or, when only a test set was read
        (a test of its own), the test set's."""
        if self.train_set is None and self.test_set is not None and self.test_dir is not None:
            return self.test_dir
        return self.train_dir

    @property
    def image_size(self) -> tuple[int, int]:
        if self.train_set is not None:
            return self.val_set.dataset.image_size
        manifest = read_manifest(self._windows_root())
        return manifest.height, manifest.width

    @property
    def frame(self) -> dict[str, Any]:
        """The training windows' frame (the manifest's ``frame``: robot pixel, heading up)."""
        if self.train_set is not None:
            return self.val_set.dataset.frame
        return dict(read_manifest(self._windows_root()).frame)

    @property
    def annotation_settings(self) -> dict[str, Any]:
        """The annotation settings the training set was generated with (its manifest's ``generator``): a
        checkpoint records the start/goal disc radius and the goal margin from them
        (:func:`spade.models.modelfile.checkpoint_entry`)."""
        return dict(read_manifest(self._windows_root()).generator)

    @property
    def resolution(self) -> float:
        """Metres per pixel of the training windows."""
        if self.train_set is not None:
            return float(self.val_set.dataset.resolution)
        return float(read_manifest(self._windows_root()).resolution)

    def _loader(self, dataset: Subset, shuffle: bool, batch_size: int, evaluation: bool = False) -> DataLoader:
        sampler = self._evaluation_sampler(dataset) if evaluation else None
        return DataLoader(
            dataset,
            batch_size=batch_size,
            shuffle=shuffle if sampler is None else None,
            sampler=sampler,
            num_workers=self.num_workers,
            pin_memory=self.pin_memory,
            persistent_workers=self.persistent_workers,
            drop_last=False,
        )

    def train_dataloader(self) -> DataLoader:
        return self._loader(self.train_set, True, self.batch_size)

    def _evaluation_sampler(self, dataset: Subset) -> UnrepeatedDistributedSampler | None:
        """Under DDP, each instance of a validation/test set on exactly one rank.

        Lightning's default DistributedSampler pads the set with repeated instances to give every rank the same
        number of batches, so synced metrics would count those twice (43 test instances on 2 ranks -> 44).
        Evaluation needs no equal batch counts: metric states sync once, at epoch end.
        """
        trainer = self.trainer
        if trainer is None or trainer.world_size < 2 or len(dataset) < trainer.world_size:
            return None
        return UnrepeatedDistributedSampler(dataset, num_replicas=trainer.world_size, rank=trainer.global_rank,
                                            shuffle=False)

    def val_dataloader(self) -> DataLoader:
        return self._loader(self.val_set, False, self.eval_batch_size, evaluation=True)

    def test_dataloader(self) -> DataLoader:
        return self._loader(self.test_set, False, self.eval_batch_size, evaluation=True)

    def _plausible_mean(self, batch: dict) -> Any:
        """BC on the plausible set (``target_source=plausible_mean``): the target is the pixelwise mean of the
        demonstration and its alternatives drawn as targets (:func:`spade.data.plausible.ceiling_map`)."""
        if batch.get("alternatives") is None:
            raise DatasetError(f"data.target_source=plausible_mean needs a training set with alternative "
                               f"demonstrations; {self.train_dir} has none: generate it with them "
                               "(data.train_generate.set: [{alternatives: {count: 16}}]) or set "
                               "data.target_source=demonstration")
        h, w = batch["path"].shape[-2:]
        images, mask = plausible_images(batch["waypoints"], batch["alternatives"], h, w, self.target_width_px)
        return ceiling_map(images, mask).to(batch["path"].dtype)

    def on_after_batch_transfer(self, batch: dict, dataloader_idx: int) -> dict:
        """Add ``target`` (the path widened to ``target_width_px``, what the models learn) and, in training,
        mirror half the batch when ``augment=mirror``."""
        batch = {**batch, "target": widen_path(batch["path"], self.target_width_px)}
        if self.target_source == "plausible_mean" and self.trainer is not None and self.trainer.training:
            batch["target"] = self._plausible_mean(batch)
        if self.augment == "mirror" and self.trainer is not None and self.trainer.training:
            return augment_batch(batch, float(self.frame["robot_px"][0]))
        return batch
