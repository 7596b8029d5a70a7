"""Lightning callbacks of SPADE."""

from __future__ import annotations

import statistics
import time

import lightning as L
import torch
from lightning.pytorch.callbacks import Callback

from spade.models import count_parameters


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
    times = []
    for i in range(warmup + runs):
        if device.type == "cuda":
            torch.cuda.synchronize()
        t0 = time.perf_counter()
        net(*args)
        if device.type == "cuda":
            torch.cuda.synchronize()
        if i >= warmup:
            times.append((time.perf_counter() - t0) * 1000)
    net.train(was_training)
    return statistics.median(times)


class ModelInfo(Callback):
    """Logs the network's trainable parameter count and batch-1 inference latency once, when fitting starts."""

    def __init__(self, latency_runs: int = 20) -> None:
        self.latency_runs = latency_runs

    def on_fit_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        net = pl_module.net
        dm = trainer.datamodule
        h, w = dm.image_size if dm is not None else (128, 128)
        info = {"model/params": float(count_parameters(net))}
        if self.latency_runs > 0 and trainer.is_global_zero:
            info["model/latency_b1_ms"] = batch1_latency_ms(net, (net.in_channels, h, w), runs=self.latency_runs)
        for logger in trainer.loggers:
            logger.log_metrics(info, step=0)
