"""``StudentModule``: the compact U-Net policy trained by BC, optionally plus the diffusion margin of a frozen
diffusion expert (DBC / Cond-DBC)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import torch
import torch.nn.functional as F

from spade.models.builders import build_model
from spade.models.modelfile import load_lightning
from spade.training.base import PathPlanningModule
from spade.training.expert_mismatch import ExpertMismatchError  # noqa: F401  (raised by ExpertModule.check_compatible)
from spade.training.margin import DiffusionMargin, MarginConfig, legacy_margin_options
from spade.training.module_options import StudentOptions
from spade.data.plausible import plausible_images
from spade.training.base import pretrained_weights
from spade.training.expert_module import ExpertModule

if TYPE_CHECKING:
    from spade.training.expert_module import ExpertModule


class StudentModule(PathPlanningModule):
    """BC (binary cross-entropy on logits) plus ``lambda_dm`` x the diffusion margin of a frozen expert.

    The options are checked by :class:`~spade.training.module_options.StudentOptions` (the margin's by
    :class:`~spade.training.margin.MarginConfig`), the same checks as ``spade.train``'s preflight.

    Args:
        size: student preset (``small``, ``medium``, ``large``, or a smaller test preset).
        margin: None for plain BC, else a dict (the ``conf/margin`` group) with ``expert_ckpt`` (an
            :class:`ExpertModule` checkpoint) and the :class:`~spade.training.margin.MarginConfig` options
            (lambda_dm, clip, antithetic, num_noise, t_min, t_max, batch_terms, expert). The expert is loaded
            when fitting starts; it is never part of this module's checkpoint, so a deployed student needs no
            expert.
        optimizer: a ``_partial_`` optimiser factory (AdamW lr 1e-3 when None).
        bc_pos_weight: weight of the path pixels in the BCE (``pos_weight`` of
            :func:`torch.nn.functional.binary_cross_entropy_with_logits`). None or 1 is the paper's plain BCE. A path
            covers about 1-2% of a window, so a briefly trained student keeps every pixel below 0.5 and no path can
            be extracted; a weight of a few (the quickstart uses 4) makes it commit to a path early.
        guidance: the name older student checkpoints keep ``margin`` under (``weight`` for
            ``lambda_dm``): read as ``margin`` (:func:`~spade.training.margin.legacy_margin_options`), so that
            such checkpoints load with their margin; never saved.
    """

    role = "student"

    def __init__(
        self,
        size: str = "medium",
        margin: dict | None = None,
        init_ckpt: str | None = None,
        optimizer: Callable[..., torch.optim.Optimizer] | None = None,
        lr_scheduler: Callable[..., Any] | None = None,
        metrics: dict | None = None,
        val_metric_batches: int | None = None,
        grid_size: int = 8,
        bc_pos_weight: float | None = None,
        guidance: dict | None = None,
    ) -> None:
        if guidance is not None:  # a checkpoint written before the rename: its hparams say guidance (weight)
            if margin is not None:
                raise ValueError("give the margin's options as margin only, not also under their old name guidance")
            margin = legacy_margin_options(guidance)
        options = StudentOptions(size=size, bc_pos_weight=bc_pos_weight, init_ckpt=init_ckpt, margin=margin)
        super().__init__(optimizer, metrics, val_metric_batches, grid_size)
        self.lr_scheduler_factory = lr_scheduler  # see PathPlanningModule.configure_optimizers
        # logger=False: the checkpoint keeps them; SPADE logs the run's method as params itself
        # (spade.tracking.params), so Lightning logs no second, unprefixed copy of them
        self.save_hyperparameters(ignore=["optimizer", "lr_scheduler", "guidance"], logger=False)  # margin as mapped
        self.bc_pos_weight = None if options.bc_pos_weight in (None, 1, 1.0) else float(options.bc_pos_weight)
        self.net = build_model("student", options.size)
        if init_ckpt:
            self.load_pretrained(init_ckpt)
        self.margin_cfg: MarginConfig | None = None
        if margin:
            self.margin_cfg = MarginConfig.from_options(margin)
            ckpt = margin.get("expert_ckpt")
            if not ckpt:
                raise ValueError("the margin needs expert_ckpt: the path of a trained ExpertModule checkpoint")
            if not Path(ckpt).is_file():
                raise FileNotFoundError(
                    f"margin expert checkpoint {ckpt} does not exist; train one with "
                    "`python -m spade.train +experiment=<expert experiment>` and pass its checkpoint path"
                )
        self._margin: list[DiffusionMargin] = []  # kept out of the module tree: never checkpointed or optimised
        # Per-epoch guidance activity: (epoch, share of active margins, mean clipped margin) of every finished
        # training epoch (on_train_epoch_end), logged as margin/active and margin/value with step = epoch.
        self.margin_history: list[tuple[int, float, float]] = []
        self._margin_sums = torch.zeros(3)  # sum of active shares x n, sum of L_DM x n, n

    def load_pretrained(self, ckpt: str | Path) -> None:
        """Initialise the network from another student's checkpoint (fine-tuning), checking it is the same net."""
        weights = pretrained_weights(ckpt, "student", self.net.config, "net.",
                                     "set model.size to the pretrained student's size")
        self.net.load_state_dict(weights)

    # -- the diffusion margin ------------------------------------------------------------------------------
    @property
    def margin(self) -> DiffusionMargin | None:
        return self._margin[0] if self._margin else None

    def load_margin(self, image_size: tuple[int, int] | None = None, encoding: str | None = None) -> None:
        """Load the frozen expert named by ``margin.expert_ckpt`` as the :class:`ExpertModule` it was trained in
        (``load_from_checkpoint``, safely) and build the margin from it (:meth:`use_expert`); once."""
        if self.margin_cfg is None or self._margin:
            return
        ckpt = self.hparams.margin["expert_ckpt"]
        self.use_expert(load_lightning(ExpertModule, ckpt), image_size, source=str(ckpt), encoding=encoding)

    def use_expert(self, expert: ExpertModule, image_size: tuple[int, int] | None = None,
                   source: str = "the expert", encoding: str | None = None) -> None:
        """The margin of ``expert`` (:meth:`DiffusionMargin.from_expert`: frozen, its EMA denoiser and noise
        schedule), after checking it against this student's data and the kind of expert the method needs."""
        if self.margin_cfg is None:
            raise ValueError("this student has no margin options (margin=null): nothing to use an expert for")
        expert.check_compatible(in_channels=self.net.in_channels, image_size=image_size, source=source,
                                encoding=encoding)
        self.margin_cfg.check_expert(expert.conditional, source)
        margin = DiffusionMargin.from_expert(expert, self.margin_cfg)
        self._margin[:] = [margin.to(device=self.device, dtype=self.dtype)]

    def setup(self, stage: str) -> None:
        if stage == "fit" and self.margin_cfg is not None:
            dm = getattr(self.trainer, "datamodule", None) if self._trainer is not None else None
            self.load_margin(getattr(dm, "image_size", None), getattr(dm, "encoding", None))

    def _apply(self, fn: Callable, recurse: bool = True) -> StudentModule:
        """Move and cast the frozen expert with the student (``.to(device)``, ``.to(dtype)``, ``.double()``,
        ``.half()``, ``.cuda()``: every one of them goes through ``nn.Module._apply``). The margin is held outside
        the module tree so that it stays out of ``state_dict`` (checkpoints) and ``parameters()`` (the optimiser);
        registering it as a submodule would put the expert's weights into every student checkpoint. Lightning has
        no public hook that sees every cast (``on_fit_start`` runs once, after the trainer's move), so the
        override is torch's own extension point for modules holding state outside ``_modules``."""
        super()._apply(fn, recurse)
        for margin in getattr(self, "_margin", ()):  # absent while nn.Module.__init__ runs
            margin._apply(fn, recurse)
        return self

    # -- steps ---------------------------------------------------------------------------------------------
    def forward(self, state: torch.Tensor) -> torch.Tensor:
        """Path logits (B, 1, H, W) for a state (B, 3, H, W)."""
        return self.net(state)

    def predict_paths(self, batch: dict) -> torch.Tensor:
        return torch.sigmoid(self(batch["state"]))

    def bc_loss(self, logits: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        """Pixel-wise binary cross-entropy on logits, path pixels weighted by ``bc_pos_weight``."""
        pos_weight = None
        if self.bc_pos_weight is not None:
            pos_weight = torch.tensor(self.bc_pos_weight, dtype=logits.dtype, device=logits.device)
        return F.binary_cross_entropy_with_logits(logits, target, pos_weight=pos_weight)

    def losses(self, batch: dict) -> dict[str, torch.Tensor]:
        """BC on the labelled instances (all, unless the batch says ``labelled``: states without a demonstration,
        ``data.unlabelled_dir``, get no BC term) plus ``lambda_dm`` x the margin on every instance."""
        logits = self(batch["state"])
        target = batch.get("target", batch["path"]).to(logits.dtype)
        labelled = batch.get("labelled")
        if labelled is None or bool(labelled.all()):
            labelled = None
            out = {"loss_bc": self.bc_loss(logits, target)}
        elif bool(labelled.any()):
            out = {"loss_bc": self.bc_loss(logits[labelled], target[labelled])}
        else:
            out = {"loss_bc": logits.sum() * 0.0}
        total = out["loss_bc"]
        if self.margin is not None:
            plausible = self._plausible(batch, logits) if self.margin.oracle or labelled is not None else None
            loss_dm, active = self.margin(torch.sigmoid(logits), target, batch["state"].to(logits.dtype),
                                          plausible=plausible, labelled=labelled)
            out.update(loss_dm=loss_dm, margin_active=active)
            total = total + self.margin_cfg.lambda_dm * loss_dm
        elif labelled is not None:
            raise ValueError("this training set has states without demonstrations (data.unlabelled_dir), which only "
                             "a diffusion margin can use: set a margin (margin=cond_dbc or margin=oracle) or drop "
                             "data.unlabelled_dir")
        out["loss"] = total
        return out

    def _plausible(self, batch: dict, logits: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor] | None:
        """Each instance's plausible set drawn as training targets, for the oracle teacher and the reference samples
        of unlabelled states (None where the batch has no alternatives)."""
        if batch.get("alternatives") is None:
            return None
        width = self._target_width()
        images, mask = plausible_images(batch["waypoints"], batch["alternatives"], *logits.shape[-2:], width)
        return images.to(logits.dtype), mask

    def training_step(self, batch: dict, batch_idx: int) -> torch.Tensor:
        parts = self.losses(batch)
        self.check_finite(parts["loss"], parts)
        n = batch["state"].shape[0]
        self.log_dict({f"train/{k}": v for k, v in parts.items()}, prog_bar=True, batch_size=n)
        if "margin_active" in parts:
            step = torch.stack([parts["margin_active"].detach() * n, parts["loss_dm"].detach() * n,
                                torch.tensor(float(n), device=self.device)])
            self._margin_sums = self._margin_sums.to(step) + step
        return parts["loss"]

    def on_train_epoch_start(self) -> None:
        self._margin_sums = torch.zeros(3, device=self.device)

    def on_train_epoch_end(self) -> None:
        """Log the epoch's guidance activity (``margin/active``: the share of samples whose margin was > 0;
        ``margin/value``: the mean clipped margin, L_DM) with step = epoch, so that a reader sees whether the
        margin still acted after the first epoch."""
        if self.margin is None:
            return
        sums = self.trainer.strategy.reduce(self._margin_sums.clone(), reduce_op="sum")
        if float(sums[2]) <= 0:
            return
        active, value = float(sums[0] / sums[2]), float(sums[1] / sums[2])
        self.margin_history.append((int(self.current_epoch), active, value))
        for logger in self.loggers:
            logger.log_metrics({"margin/active": active, "margin/value": value}, step=int(self.current_epoch))

    def validation_losses(self, batch: dict) -> dict[str, torch.Tensor]:
        logits = self(batch["state"])
        return {"val/loss_bc": self.bc_loss(logits, batch.get("target", batch["path"]).to(logits.dtype))}
