"""SPADE's MLflow logger: Lightning's ``MLFlowLogger`` with SPADE's routing of metrics (``conf/logger/mlflow.yaml``).

What a run shows in the MLflow UI is decided here, where every metric passes:

* **References are held back.** The classical baselines' figures (``test/baseline/<name>/...``, logged by the
  test step next to the model's) and the untrained model's (``untrained/...``, ``test_untrained=true``) are not
  logged on the run: they are kept in :attr:`MLFlowLogger.held` and become the run's child runs
  (:func:`~spade.tracking.predictors.log_predictor_runs`, with the model's metric names), where the runs
  table and the charts compare them with the model. The run's own metrics are the model's.
* **Test figures at one step.** Every ``test/...`` and ``closed_loop/...`` figure is logged at
  :data:`~spade.tracking.predictors.TEST_STEP` (0), the step the child runs use: the charts put the
  model, its baselines and the untrained model side by side instead of at two ends of the x axis. The run's MLflow
  Model (logged when the run finishes; MLflow links to it the run's metrics at its step, 0) carries the test figures
  and the model's own ``model/params`` and ``model/latency_b1_ms``, nothing of the references.
* **Guidance on the validation's axis.** ``margin/active`` and ``margin/value``, which the student logs once an
  epoch with step = epoch, are logged at the global step of that epoch's last logged metrics (its validation), so
  that a chart of ``margin/active`` and one of ``val/ape_cm`` share their x axis; the run is tagged
  ``spade.margin_step=global`` (:mod:`spade.tracking.progress_picture` reads either kind).

* **The run opens and closes once.** A fresh SQLite store's tables are created under a lock before the logger
  opens it (:func:`~spade.tracking.client.ensure_store`: two runs started together on an empty store both run);
  the experiment a parallel job created at the same moment is looked up again rather than failing the run. A run
  whose record keeps it (:meth:`MLFlowLogger.keep_open`, :class:`~spade.tracking.callback.RunRecord`: from its first
  stage until its record is complete) stays RUNNING through Lightning's end-of-stage ``finalize("success")``, so
  that the test and the run's record are written into an open run; the record then ends it
  (:meth:`MLFlowLogger.close`). A run the record marked KILLED, FAILED or deleted (:meth:`MLFlowLogger.ended`)
  keeps that when Lightning then finalizes it as failed.

The class keeps Lightning's name so that code that recognises an MLflow logger by its class name (the model file's
``mlflow_run_id``) still does; it is a subclass, so ``isinstance(..., lightning.pytorch.loggers.MLFlowLogger)``
holds too.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from lightning.pytorch.loggers import MLFlowLogger as LightningMLFlowLogger
from lightning.pytorch.utilities import rank_zero_only

from spade.tracking.client import ensure_store
from spade.tracking.predictors import TEST_STEP, is_reference_metric
from spade.tracking.progress_picture import MARGIN_STEP_TAG

MARGIN_PREFIX = "margin/"
TEST_STEP_PREFIXES = ("test/", "closed_loop/")  # the figures logged at TEST_STEP, as the child runs log theirs


class MLFlowLogger(LightningMLFlowLogger):
    """Lightning's MLflow logger with SPADE's routing of metrics (see the module)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        if rank_zero_only.rank == 0:
            ensure_store(kwargs.get("tracking_uri"))  # a fresh store's tables, created by one process at a time
        super().__init__(*args, **kwargs)
        self.held: dict[str, float] = {}  # the references' figures, for the child runs and the description
        self._kept_open = False  # the run's record ends the run, not Lightning's end of a stage (keep_open)
        self._ended_as: str | None = None  # KILLED / FAILED / DELETED: how the run's record ended it (ended)
        self._closed = False  # ended by its record (close): Lightning's finalize has nothing left to end
        self._epoch_step: dict[int, int] = {}  # epoch -> the last global step logged in it
        self._margin_tagged = False

    @property
    def experiment(self) -> Any:
        """Lightning's ``MlflowClient`` with the run open; an experiment that a parallel job created between
        Lightning's lookup and its ``create_experiment`` is looked up again instead of failing the run."""
        from mlflow.exceptions import MlflowException

        try:
            return super().experiment
        except MlflowException:
            return super().experiment  # created meanwhile by a parallel job: this lookup finds it

    def keep_open(self) -> None:
        """Leave the run RUNNING at the end of each stage, until :meth:`close` (the run's record ends it)."""
        self._kept_open = True

    def close(self, status: str = "success") -> None:
        """End a run kept open (:meth:`keep_open`): its record is complete."""
        self._kept_open = False
        self.finalize(status)
        self._closed = True

    def ended(self, status: str) -> None:
        """The run was marked ``status`` (KILLED / FAILED, or deleted: ``DELETED``) by its record: Lightning's
        ``finalize("failed")``, next, keeps it, and nothing holds the run open any more."""
        self._ended_as = status
        self._kept_open = False

    @rank_zero_only
    def finalize(self, status: str = "success") -> None:
        """End the run, unless its record keeps it open (:meth:`keep_open`); a run marked KILLED or FAILED keeps
        that status (:meth:`ended`), a deleted one is left alone."""
        if self._closed or (status == "success" and self._kept_open):
            return
        if self._ended_as == "DELETED":
            return  # a refused run, deleted (spade.tracking.runs.refused_before_work): nothing to close
        super().finalize(self._ended_as or status)

    @rank_zero_only
    def log_metrics(self, metrics: Mapping[str, float], step: int | None = None) -> None:
        metrics = dict(metrics)
        held = {k: float(v) for k, v in metrics.items() if is_reference_metric(k)}
        self.held.update(held)
        kept = {k: v for k, v in metrics.items() if k not in held}
        test = {k: v for k, v in kept.items() if k.startswith(TEST_STEP_PREFIXES)}
        margin = {k: v for k, v in kept.items() if k.startswith(MARGIN_PREFIX)}
        rest = {k: v for k, v in kept.items() if k not in test and k not in margin}
        if "epoch" in rest and step is not None and not test:
            epoch = int(rest["epoch"])
            self._epoch_step[epoch] = max(int(step), self._epoch_step.get(epoch, 0))
        if test:
            super().log_metrics(test, step=TEST_STEP)
        if margin:
            super().log_metrics(margin, step=self._margin_step(step))
        if rest:
            super().log_metrics(rest, step=step)

    def _margin_step(self, epoch: int | None) -> int | None:
        """The global step of ``epoch``'s last logged metrics (its validation); ``epoch`` itself when none was
        logged (a run without validation), and the run then keeps the old meaning (no tag)."""
        if epoch is None or int(epoch) not in self._epoch_step:
            return epoch
        if not self._margin_tagged:
            self.experiment.set_tag(self.run_id, MARGIN_STEP_TAG, "global")
            self._margin_tagged = True
        return self._epoch_step[int(epoch)]


def held_metrics(logger: Any) -> dict[str, float]:
    """The references' figures ``logger`` held back (empty for another logger)."""
    return dict(getattr(logger, "held", None) or {})
