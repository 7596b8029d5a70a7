"""What the student and the expert modules share: metrics per stage, prediction pictures, optimiser, NaN guard."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import lightning as L
import torch

from spade.metrics.path_metrics import BASELINE_PLANNER_KEYS, INSTANCES_ARTIFACT, PathMetrics
from spade.metrics.plausible import REFERENCES, reference_maps, reference_polylines
from spade.models.modelfile import write_checkpoint_entry
from spade.training.logging_utils import log_image
from spade.training.visualize import TestRecords, prediction_grid
from spade.metrics.baselines import BASELINES, batch_baseline_polylines, draw_polylines
from spade.models.modelfile import load_checkpoint, read_info
from spade.training.logging_utils import log_table_csv


class PathPlanningModule(L.LightningModule):
    """Base of :class:`StudentModule` and :class:`ExpertModule`.

    Subclasses implement ``predict_paths(batch) -> probabilities (B, 1, H, W)`` and the training step; this
    class evaluates ``predict_paths`` with APE / Hd19 / FID in validation and test, logs a picture grid of
    predictions each validation epoch, and builds the optimiser from a Hydra ``_partial_`` callable.
    """

    def __init__(self, optimizer: Callable[..., torch.optim.Optimizer] | None, metrics: dict | None,
                 val_metric_batches: int | None, grid_size: int) -> None:
        super().__init__()
        self.optimizer_factory = optimizer
        metrics = dict(metrics or {})
        # validation selects checkpoints on the paper's figures (val/score_cm): the planner's decoding is for tests
        self.val_metrics = PathMetrics(**{**metrics, "planner": False})
        self.test_metrics = PathMetrics(**metrics, record_instances=True)
        self.val_metric_batches = val_metric_batches
        self.grid_size = grid_size

    role: str = "model"

    # -- to implement --------------------------------------------------------------------------------------
    def predict_paths(self, batch: dict) -> torch.Tensor:  # pragma: no cover - abstract
        raise NotImplementedError

    # -- shared machinery ----------------------------------------------------------------------------------
    #: Steps between two looks at the loss's finiteness: every step on a CPU (free there); on an accelerator a
    #: look makes the host wait for the device, so the first non-finite step is recorded on the device and read
    #: every this many steps (one host sync), the message still naming that step.
    FINITE_CHECK_EVERY_ACCELERATOR = 16

    def finite_check_every(self, device: torch.device) -> int:
        return 1 if device.type == "cpu" else self.FINITE_CHECK_EVERY_ACCELERATOR

    def check_finite(self, loss: torch.Tensor, parts: dict[str, torch.Tensor]) -> None:
        """Stop on a NaN or inf loss with a message naming the (first such) step and the loss terms."""
        every = self.finite_check_every(loss.device)
        step = int(self.global_step)
        if every <= 1:
            if not torch.isfinite(loss):
                self._raise_non_finite(step, loss, parts)
            return
        first = getattr(self, "_first_non_finite", None)
        if first is None or first.device != loss.device:
            first = torch.full((), -1, dtype=torch.long, device=loss.device)
        bad = ~torch.isfinite(loss.detach())
        self._first_non_finite = torch.where(bad & (first < 0), torch.full_like(first, step), first)
        if step % every == every - 1:
            seen = int(self._first_non_finite)  # the one host sync in ``every`` steps
            if seen >= 0:
                self._raise_non_finite(seen, loss, parts, current=step)

    def _raise_non_finite(self, step: int, loss: torch.Tensor, parts: dict[str, torch.Tensor],
                          current: int | None = None) -> None:
        terms = ", ".join(f"{k}={float(v):.4g}" for k, v in parts.items())
        seen = "" if current is None else f" (seen at step {current}; these terms are that step's)"
        raise FloatingPointError(
            f"non-finite training loss {float(loss)} at global step {step} (epoch {self.current_epoch}){seen}: "
            f"{terms}. Lower the learning rate or the margin weight (model.margin.lambda_dm), or check the data."
        )

    def on_save_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        """The ``spade`` entry (role, network, training windows, MLflow run): see :mod:`spade.models.modelfile`."""
        datamodule = getattr(self._trainer, "datamodule", None) if self._trainer is not None else None
        write_checkpoint_entry(checkpoint, self.role, self.net, datamodule, self.loggers)

    def configure_optimizers(self) -> Any:
        """The optimiser from ``optimizer_factory`` (AdamW lr 1e-3 when None) and, when the subclass holds an
        ``lr_scheduler_factory`` (a ``_partial_`` such as :func:`spade.training.schedules.warmup_cosine`, called
        with the optimiser and ``total_steps``, the trainer's estimated optimisation steps), its scheduler, stepped
        every optimisation step."""
        params = [p for p in self.parameters() if p.requires_grad]
        if self.optimizer_factory is None:
            optimizer = torch.optim.AdamW(params, lr=1e-3)
        else:
            optimizer = self.optimizer_factory(params=params)
        scheduler_factory = getattr(self, "lr_scheduler_factory", None)
        if scheduler_factory is None:
            return optimizer
        import math

        total = self.trainer.estimated_stepping_batches if self._trainer is not None else None
        if total is None or not math.isfinite(float(total)) or int(total) < 1:
            raise ValueError(f"a learning-rate schedule needs a finite number of training steps (trainer.max_epochs or "
                             f"trainer.max_steps), the trainer estimates {total}")
        scheduler = scheduler_factory(optimizer=optimizer, total_steps=int(total))
        return {"optimizer": optimizer, "lr_scheduler": {"scheduler": scheduler, "interval": "step", "frequency": 1,
                                                         "name": "lr"}}

    def validation_step(self, batch: dict, batch_idx: int) -> None:
        self.log_dict(self.validation_losses(batch), batch_size=batch["state"].shape[0], sync_dist=True)
        if self.val_metric_batches is not None and batch_idx >= self.val_metric_batches:
            return
        prob = self.predict_paths(batch)
        self.val_metrics.update(prob, batch)
        if self.grid_size > 0 and not self.trainer.sanity_checking:
            self._pick_for_picture(batch, prob)

    def _pick_for_picture(self, batch: dict, prob: torch.Tensor) -> None:
        """Keep the first instance of each new scenario (validation batches come in a fixed order, so the picture
        shows the same ``grid_size`` scenarios every epoch, each a different one: a scenario's instances are
        near-duplicates)."""
        picks = self.__dict__.setdefault("_picture_picks", [])
        ids = batch.get("scenario_id")
        for i in range(prob.shape[0]):
            if len(picks) >= self.grid_size:
                return
            scenario = str(ids[i]) if ids is not None and i < len(ids) else f"#{len(picks) + 1}"
            if any(scenario == p[0] for p in picks):
                continue
            alternatives = batch.get("alternatives")
            picks.append((scenario, batch["state"][i].detach().cpu(), batch["path"][i].detach().cpu(),
                          prob[i].detach().cpu(), batch["waypoints"][i].detach().cpu(),
                          float(batch["resolution"][i]),
                          alternatives[i].detach().cpu() if alternatives is not None else None))

    def on_validation_epoch_start(self) -> None:
        self._picture_picks: list[tuple] = []

    def validation_losses(self, batch: dict) -> dict[str, torch.Tensor]:
        return {}

    def on_validation_epoch_end(self) -> None:
        picks = self.__dict__.pop("_picture_picks", None)
        if picks and not self.trainer.sanity_checking:
            stack = [torch.stack([p[k] for p in picks]) for k in (1, 2, 3, 4)]
            grid = prediction_grid(*stack, torch.tensor([p[5] for p in picks]), titles=[p[0] for p in picks],
                                   alternatives=[p[6] for p in picks])
            log_image(self.logger, grid, f"predictions/epoch{self.current_epoch:03d}.png", self.trainer.log_dir)
        if self.val_metrics.ape.total > 0:
            self.log_dict({f"val/{k}": v for k, v in self.val_metrics.compute().items()}, sync_dist=False)
        self.val_metrics.reset()

    # -- test: the model next to the classical baselines, on the same instances ---------------------------
    def on_test_epoch_start(self) -> None:
        metrics = dict(self.hparams.get("metrics") or {})
        self._baseline_metrics = {name: PathMetrics(**{**metrics, "planner_keys": BASELINE_PLANNER_KEYS},
                                                    record_instances=True).to(self.device) for name in BASELINES}
        # the references a learned planner sits between: the BC ceiling and the decoder's floor (REFERENCES)
        self._reference_metrics = {name: PathMetrics(**{**metrics, "fid": False, "planner_keys": BASELINE_PLANNER_KEYS},
                                                     record_instances=True).to(self.device) for name in REFERENCES}
        tail_cm = getattr(getattr(self.test_metrics, "ape", None), "tail_cm", None)  # a worst picture's bar
        self._test_records = TestRecords() if tail_cm is None else TestRecords(tail_cm=float(tail_cm))

    def test_step(self, batch: dict, batch_idx: int) -> None:
        self._test_with(self.predict_paths(batch), batch)

    def _test_with(self, prob: torch.Tensor, batch: dict) -> None:
        """The test of predicted probabilities ``prob``: the metrics, the records for the pictures, and the
        classical baselines on the same instances."""
        self.test_metrics.update(prob, batch)
        self._test_records.add(batch, prob)
        h, w = prob.shape[-2:]
        shapes = batch.get("shape")
        shapes = list(shapes) if isinstance(shapes, (list, tuple)) else None
        for name, polys in batch_baseline_polylines(batch["state"], batch["resolution"], shapes).items():
            # the paper's figures from the baseline drawn as an image, the planner's from its own polyline
            self._baseline_metrics[name].update(draw_polylines(polys, h, w, prob.device), batch, polylines=polys)
        references = getattr(self, "_reference_metrics", None)
        if references:
            for name, image in reference_maps(batch, self._target_width()).items():
                references[name].update(image, batch)
            for name, polys in reference_polylines(batch).items():
                references[name].update(draw_polylines(polys, h, w, prob.device), batch, polylines=polys)

    def _log_instance_rows(self) -> None:
        """Write the per-instance planner figures of the model, the baselines and the references as one CSV
        (:data:`INSTANCES_ARTIFACT`, column ``predictor``) into the run (MLflow artifact) or the log folder."""
        if self._trainer is None or self.trainer.sanity_checking:
            return
        predictors = {"model": self.test_metrics,
                      **{f"baseline/{k}": v for k, v in getattr(self, "_baseline_metrics", {}).items()},
                      **dict(getattr(self, "_reference_metrics", {}).items())}
        rows = [{"predictor": name, **row} for name, m in predictors.items() for row in m.instance_rows]
        scenarios = {row["scenario"] for row in self.test_metrics.instance_rows}
        if scenarios:  # the unit of the intervals over scenarios: a small test set says so in the summary
            self.log("test/scenarios", float(len(scenarios)), sync_dist=False)
        if rows:
            log_table_csv(self.logger, rows, INSTANCES_ARTIFACT, self.trainer.log_dir)

    def _target_width(self) -> int:
        """The training target's width in pixels (the datamodule's ``target_width_px``; 1 without one)."""
        datamodule = getattr(self._trainer, "datamodule", None) if self._trainer is not None else None
        return int(getattr(datamodule, "target_width_px", 1) or 1)

    def on_test_epoch_end(self) -> None:
        self.log_dict({f"test/{k}": v for k, v in self.test_metrics.compute().items()}, sync_dist=False)
        self._log_instance_rows()
        self.test_metrics.reset()
        for name, metrics in getattr(self, "_baseline_metrics", {}).items():
            self.log_dict({f"test/baseline/{name}/{k}": v for k, v in metrics.compute().items()}, sync_dist=False)
        self._baseline_metrics = {}
        for name, metrics in getattr(self, "_reference_metrics", {}).items():
            if metrics.planner_ape.total > 0:
                self.log_dict({f"test/{name}/{k}": v for k, v in metrics.compute().items()
                               if k.startswith("planner/")}, sync_dist=False)
        self._reference_metrics = {}
        records = getattr(self, "_test_records", None)
        if records is not None and records.count and not self.trainer.sanity_checking:
            for label, picture in records.pictures().items():
                log_image(self.logger, picture, f"predictions/test_{label}.png", self.trainer.log_dir)


def pretrained_weights(ckpt: "str | Path", role: str, config: dict, prefix: str, fix: str) -> dict:
    """The weights under ``prefix`` of the ``role`` checkpoint ``ckpt`` (``model.init_ckpt``: fine-tuning), after
    checking that it exists, holds that role and the same network ``config``; ``fix`` ends the mismatch message."""
    from pathlib import Path

    a = "an" if role[0] in "aeiou" else "a"
    path = Path(ckpt)
    if not path.is_file():
        raise FileNotFoundError(f"init_ckpt={path} does not exist; pass {a} {role} checkpoint (.ckpt)")
    info = read_info(path, checkpoint=True, required=False)
    if info.get("role") != role:
        raise ValueError(f"init_ckpt={path} is a {info.get('role', 'non-SPADE')} checkpoint, not {a} {role}'s")
    if dict(info.get("config") or {}) != dict(config):
        raise ValueError(f"init_ckpt={path} holds {a} {role} {info.get('config')}, this run builds {dict(config)}: "
                         f"{fix}")
    return {k[len(prefix):]: v for k, v in load_checkpoint(path)["state_dict"].items() if k.startswith(prefix)}
