"""A training run's life: seeds that make it reproducible and resumable, its best checkpoint across a resume.

* :class:`DeterministicTraining` (a callback ``spade.train`` always adds when a seed is set) draws the training
  data order from a generator seeded by (seed, epoch) and re-seeds Python's, NumPy's and torch's global generators
  before every training batch from (seed, epoch, batch index). Augmentation, the margin's noise and timesteps and the
  expert's denoising noise all come from those global generators, so a batch's randomness depends only on where
  it is in the run: a run resumed from an epoch-end checkpoint repeats the uninterrupted run's numbers exactly,
  and nothing done before training (a prerequisite trained in the same process, an untrained-baseline test)
  changes them.
* :class:`CarryBestCheckpoint` (added by ``spade.train`` when it resumes from ``ckpt_path``) keeps the interrupted
  run's best checkpoint and score, which Lightning drops when the run folder changes, so a resumed run tests the
  checkpoint the uninterrupted run would have tested.
* :func:`run_without_stages`: a run that trains and tests nothing (``train=false test=false``, or evaluates in
  closed loop alone) still gives its callbacks their ``setup`` and ``teardown`` hooks (stage :data:`NO_STAGE`)
  and closes its loggers, as a stage would.

Signals (a SIGTERM or SIGINT ends the run through an exception, recorded as KILLED) are :mod:`spade.utils.signals`;
where a run's checkpoints are, :mod:`spade.training.checkpoint_paths`.

The MLflow run's status (its process recorded, KILLED / FAILED when it does not finish, stale RUNNING runs marked
KILLED) is kept by the run's record, :class:`spade.tracking.callback.RunRecord`, with the rest of its start and end.
"""

from __future__ import annotations

import logging
import random
from typing import Any

import lightning as L
import numpy as np
import torch
from lightning.pytorch.callbacks import Callback

from spade.tracking.callback import NO_STAGE  # the stage of a run that trains and tests nothing
from torch.utils.data import DataLoader, RandomSampler
from spade.models.modelfile import load_checkpoint

log = logging.getLogger(__name__)

_DATA, _BATCH = 1, 2  # streams of derived_seed


def derived_seed(seed: int, *keys: int) -> int:
    """A 32-bit seed for (seed, keys...): independent streams for independent uses (NumPy's SeedSequence)."""
    return int(np.random.SeedSequence([int(seed) % 2**32, *[int(k) for k in keys]]).generate_state(1)[0])


def reseed_globals(seed: int) -> None:
    """Seed Python's, NumPy's and torch's (CPU and CUDA) global generators."""
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


class DeterministicTraining(Callback):
    """Training randomness as a function of (seed, epoch, batch index) only; see the module docstring.

    The data order: the training loader's sampler (a ``RandomSampler``) and its worker seeds draw from a
    generator seeded by (seed, epoch) when the loader is made and whenever Lightning starts an epoch
    (``set_epoch``), not from the global generator, whose position depends on everything done before.
    A run resumed from a checkpoint saved mid-epoch restarts that epoch's data from its beginning (Lightning
    keeps no position inside a plain ``DataLoader``); ``spade.train`` checkpoints at epoch ends.

    Lightning offers no hook that seeds a loader per epoch: its fit loop calls ``sampler.set_epoch(epoch)`` when
    the sampler has one (a ``DistributedSampler`` does; a ``RandomSampler`` does not), so this callback gives the
    sampler that method rather than writing any of Lightning's own fields. The datamodule's ``train_dataloader``
    is wrapped on the instance (the hook Lightning calls), marked so that a second fit does not wrap it twice.
    """

    def __init__(self, seed: int) -> None:
        self.seed = int(seed)

    # -- data order ------------------------------------------------------------------------------------------
    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        """Wrap the loader before anything builds it: ``setup`` runs before ``configure_optimizers``, whose
        learning-rate schedule asks ``trainer.estimated_stepping_batches``, which builds the training loader
        (``on_fit_start`` would come after it, and the fit would keep that unseeded loader)."""
        if stage != "fit":
            return
        dm = trainer.datamodule
        if dm is None or getattr(dm, "_spade_seeded_loader", False):
            return
        make_loader = dm.train_dataloader

        def train_dataloader() -> Any:  # the datamodule's own loader, with the seeded generator attached
            loader = make_loader()
            self.seed_loader(loader, trainer.fit_loop.epoch_progress.current.processed)
            return loader

        dm.train_dataloader = train_dataloader  # instance attribute: Lightning calls it when fitting starts
        dm._spade_seeded_loader = True

    def seed_loader(self, loader: Any, epoch: int) -> None:
        """Attach (seed, epoch)-seeded generators: one for the sampler's order, one for the workers' base seed.

        Two generators, because Lightning creates the first iterator of a fit (which draws the base seed) before
        it calls ``set_epoch`` and draws the order after it, and later iterators after it: with one generator
        the order would depend on which of the two came first.
        """
        if not isinstance(loader, DataLoader):
            return
        order, workers = torch.Generator(), torch.Generator()

        def set_epoch(e: int) -> None:  # called by Lightning's fit loop at every epoch start
            order.manual_seed(derived_seed(self.seed, _DATA, e, 0))
            workers.manual_seed(derived_seed(self.seed, _DATA, e, 1))

        set_epoch(epoch)
        loader.generator = workers  # the worker processes' base seed
        sampler = loader.sampler
        if isinstance(sampler, RandomSampler):
            sampler.generator = order
            sampler.set_epoch = set_epoch

    # -- everything else ---------------------------------------------------------------------------------------
    def _reseed(self, epoch: int, batch_idx: int) -> None:
        reseed_globals(derived_seed(self.seed, _BATCH, epoch, batch_idx))

    def on_train_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._reseed(trainer.current_epoch, trainer.fit_loop.epoch_loop.batch_progress.current.completed)

    def on_train_epoch_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._reseed(trainer.current_epoch, 0)

    def on_train_batch_end(self, trainer: L.Trainer, pl_module: L.LightningModule, outputs: Any, batch: Any,
                           batch_idx: int) -> None:
        self._reseed(trainer.current_epoch, batch_idx + 1)  # for the next batch, drawn before its hooks run


# -- resume ---------------------------------------------------------------------------------------------------------


def run_without_stages(trainer: L.Trainer, model: L.LightningModule) -> None:
    """The hooks Lightning calls around a stage, for a run in which no stage runs (``train=false test=false``,
    ``spade.evaluate``'s closed loop alone): every callback's ``setup`` and ``teardown`` with stage
    :data:`NO_STAGE`, then every logger closed with ``success``; on an exception, every callback's
    ``on_exception`` and the loggers closed with ``failed``, as Lightning does. So a callback that records the run
    (:class:`spade.tracking.callback.RunRecord`) opens, completes and closes it as after a test, and the caller
    needs to know none of them."""
    try:
        for callback in trainer.callbacks:
            callback.setup(trainer, model, stage=NO_STAGE)
        for callback in trainer.callbacks:
            callback.teardown(trainer, model, stage=NO_STAGE)
    except BaseException as exc:
        for callback in trainer.callbacks:
            callback.on_exception(trainer, model, exc)
        for logger in trainer.loggers:
            logger.finalize("failed")
        raise
    for logger in trainer.loggers:
        logger.finalize("success")


class CarryBestCheckpoint(Callback):
    """Keep the interrupted run's best checkpoint and score when a run resumes from ``ckpt_path``.

    Every run has its own folder, so Lightning's ``ModelCheckpoint`` sees another ``dirpath`` on resume and drops
    ``best_model_score`` and the top-k list ("dirpath has changed"): the first validation after the resume would
    then become "best" whatever its score, and the run would test the wrong checkpoint. At the start of training
    (after Lightning restored the checkpoint) this copies the interrupted run's top-k checkpoints into the new
    folder (the old folder is never touched, so it can be resumed again) and restores the scores, so the run tests
    the checkpoint the uninterrupted run would have tested.

    ``ModelCheckpoint`` has no public way to adopt another folder's state (its ``load_state_dict`` drops the scores
    when ``dirpath`` differs, by design), so this sets its public attributes ``best_k_models``,
    ``best_model_path``, ``best_model_score`` and ``kth_*`` after copying the files: the attributes its own
    ``state_dict`` saves, nothing private.
    """

    def __init__(self, ckpt_path: str) -> None:
        self.ckpt_path = str(ckpt_path)

    def on_train_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        import shutil
        import zipfile
        from pathlib import Path

        loaded = load_checkpoint(self.ckpt_path, mmap=zipfile.is_zipfile(self.ckpt_path))
        states = loaded.get("callbacks") or {}
        for cb in trainer.checkpoint_callbacks:
            state = states.get(getattr(cb, "state_key", None))
            if not state or cb.best_model_score is not None or state.get("best_model_score") is None:
                continue  # the same folder (Lightning restored everything), or nothing to carry
            if cb.dirpath is None or state.get("monitor") != cb.monitor:
                continue
            missing = [old for old in (state.get("best_k_models") or {}) if not Path(old).is_file()]
            if missing:  # the interrupted run's folder was cleaned: its best cannot be tested, say so
                log.warning("the interrupted run's checkpoints %s are gone: the best checkpoint is chosen among the "
                            "epochs after the resume", missing)
                continue
            moved: dict[str, Any] = {}
            for old, score in (state.get("best_k_models") or {}).items():
                new = Path(cb.dirpath) / Path(old).name
                if trainer.is_global_zero and Path(old).is_file() and not new.exists():
                    new.parent.mkdir(parents=True, exist_ok=True)
                    shutil.copy2(old, new)
                moved[str(old)] = (str(new), score)
            trainer.strategy.barrier("carry_best_checkpoint")

            def where(old: Any) -> str:
                return moved.get(str(old), (str(old), None))[0] if old else ""

            cb.best_k_models = {new: score for new, score in moved.values()}
            cb.best_model_score = state["best_model_score"]
            cb.best_model_path = where(state.get("best_model_path"))
            cb.kth_best_model_path = where(state.get("kth_best_model_path"))
            if state.get("kth_value") is not None:
                cb.kth_value = state["kth_value"]
            log.info("resumed with the interrupted run's best checkpoint %s (%s = %.4g)", cb.best_model_path,
                     cb.monitor, float(cb.best_model_score))
