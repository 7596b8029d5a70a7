"""Lightning callbacks of SPADE."""

from __future__ import annotations

import lightning as L
import torch
from lightning.pytorch.callbacks import Callback

from spade.models.builders import count_parameters
from spade.utils.timing import measure
from spade.training.critic import critic_report
from spade.training.logging_utils import log_image
from spade.training.margin import DiffusionMargin, MarginConfig


@torch.inference_mode()
def batch1_latency_ms(net: torch.nn.Module, input_shape: tuple[int, ...], runs: int = 20, warmup: int = 3) -> float:
    """Median wall time (ms) of one forward pass on a batch of one, in eval mode, on the module's device."""
    was_training = net.training
    net.eval()
    device = next(net.parameters()).device
    args = [torch.zeros(1, *input_shape, device=device)]
    if hasattr(net, "condition_channels"):  # a diffusion expert: (x_t, t[, cond])
        args.append(torch.zeros(1, dtype=torch.long, device=device))
        if net.condition_channels:
            args.append(torch.zeros(1, net.condition_channels, *input_shape[1:], device=device))
    cuda = device.type == "cuda"
    if cuda:
        torch.cuda.synchronize()

    def forward() -> None:
        net(*args)
        if cuda:  # time the kernels, not their launch
            torch.cuda.synchronize()

    timing = measure(forward, runs, warmup)
    net.train(was_training)
    return timing.median_ms


class ModelInfo(Callback):
    """Logs the network's trainable parameter count and batch-1 inference latency once: when fitting starts, or when
    a test starts without a fit (``spade.evaluate``), so that every run that tests a network records its size."""

    def __init__(self, latency_runs: int = 20) -> None:
        self.latency_runs = latency_runs
        self._logged = False

    def on_fit_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._log(trainer, pl_module)

    def on_test_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if not self._logged:
            self._log(trainer, pl_module)

    def _log(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._logged = True
        net = pl_module.net
        dm = trainer.datamodule
        h, w = dm.image_size if dm is not None else (128, 128)
        info = {"model/params": float(count_parameters(net))}
        if self.latency_runs > 0 and trainer.is_global_zero:
            info["model/latency_b1_ms"] = batch1_latency_ms(net, (net.in_channels, h, w), runs=self.latency_runs)
        for logger in trainer.loggers:
            logger.log_metrics(info, step=0)


class ChannelsLast(Callback):
    """Runs the model and its image batches in channels_last (NHWC) memory format.

    Convolutions in bf16/fp16 on tensor-core GPUs (Volta and newer) are fastest in NHWC; PyTorch keeps the format
    through the network once the weights and inputs have it. The numbers computed are the same; checkpoints store
    plain tensors whatever their memory format. Enabled by ``trainer=gpu`` (conf/callbacks/extra/channels_last.yaml).
    """

    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        pl_module.to(memory_format=torch.channels_last)

    @staticmethod
    def convert(batch: object) -> None:
        """Turn every 4-D tensor of a dict batch into channels_last, in place (the step receives the same dict)."""
        if isinstance(batch, dict):
            for key, value in batch.items():
                if isinstance(value, torch.Tensor) and value.dim() == 4:
                    batch[key] = value.contiguous(memory_format=torch.channels_last)

    def on_train_batch_start(self, trainer: L.Trainer, pl_module: L.LightningModule, batch: object,
                             batch_idx: int) -> None:
        self.convert(batch)

    def on_validation_batch_start(self, trainer: L.Trainer, pl_module: L.LightningModule, batch: object,
                                  batch_idx: int, dataloader_idx: int = 0) -> None:
        self.convert(batch)

    def on_test_batch_start(self, trainer: L.Trainer, pl_module: L.LightningModule, batch: object,
                            batch_idx: int, dataloader_idx: int = 0) -> None:
        self.convert(batch)


class CriticReport(Callback):
    """At the end of an expert's test, the expert as a critic (:func:`spade.training.critic.critic_report`) on
    the test set, for each margin formulation in ``formulations`` (name -> :class:`MarginConfig` options; the
    paper's, ``{}``, logs ``critic/...``, any other ``critic_<name>/...``), with a picture per formulation.

    Students and runs without a test are left alone; so is every rank but the first under DDP.
    """

    def __init__(self, formulations: dict[str, dict] | None = None, max_instances: int | None = 96,
                 draws_per_band: int = 2, bands: int = 5, seed: int = 0) -> None:
        self.formulations = dict(formulations if formulations is not None else {"paper": {}})
        self.max_instances, self.draws_per_band, self.bands, self.seed = max_instances, draws_per_band, bands, seed

    @staticmethod
    def prefix(name: str) -> str:
        return "critic/" if name == "paper" else f"critic_{name}/"

    def on_test_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if getattr(pl_module, "role", None) != "expert" or not trainer.is_global_zero or trainer.sanity_checking:
            return
        dm = trainer.datamodule
        loader = dm.test_dataloader()
        for name, options in self.formulations.items():
            config = MarginConfig(**dict(options))
            margin = DiffusionMargin.from_expert(pl_module, config)
            with torch.inference_mode(False):
                metrics, picture = critic_report(
                    margin, loader, float(dm.frame["robot_px"][0]), dm.target_width_px, draws_per_band=self.draws_per_band,
                    bands=self.bands, seed=self.seed, max_instances=self.max_instances,
                    title=f"{name} margin: score={config.score}, agent_input={config.agent_input}")
            prefix = self.prefix(name)
            renamed = {prefix + k[len("critic/"):]: v for k, v in metrics.items()}
            for logger in trainer.loggers:
                logger.log_metrics(renamed, step=trainer.global_step)
            log_image(pl_module.logger, picture, f"critic/{name}.png", trainer.log_dir)
            worst = min(((v, k) for k, v in renamed.items() if k.count("/") == 2 and "/win/" in k and v == v),
                        default=None)
            if worst is not None:
                print(f"critic ({name} margin): the demonstration beats every corruption on at least "
                      f"{worst[0]:.0%} of test instances (weakest: {worst[1].split('/')[-1]})", flush=True)
