"""The trainer's speed options (``conf/trainer``): precision and channels_last, with
``auto`` values resolved on the machine the run starts on (:mod:`spade.utils.hardware`).

``conf/trainer/cpu.yaml`` (and every trainer config built on it) instantiates :func:`build_trainer` rather than
``lightning.Trainer``: it takes Lightning's arguments plus the options below, resolves them, adds the callbacks
they need and returns a plain :class:`lightning.pytorch.Trainer`.

- ``precision``: Lightning's own (``32-true``, ``bf16-mixed``, ...), or ``auto``: ``bf16-mixed`` where bf16 is
  native (a GPU of Ampere or newer, a CPU with AVX-512 BF16 or AMX), else ``32-true``. ``bf16-mixed`` is
  Lightning's autocast: fp32 master weights and optimiser, convolutions in bf16, losses in fp32 (autocast keeps
  ``binary_cross_entropy_with_logits`` and reductions of fp32 targets in fp32).
- ``channels_last``: ``true``/``false``/``auto`` (``auto``: on where oneDNN (CPU) or cuDNN (GPU) runs NHWC
  convolutions natively; :class:`~spade.training.callbacks.ChannelsLast`). The same numbers up to summation order.

The margin's frozen expert held in bf16 (:func:`use_bf16_expert`) is a lever the bench measures
(``spade.bench`` ``training.levers``: ``expert_bf16``); it did not pay (docs/results/speed.md), so it is no trainer
option.
"""

from __future__ import annotations

from typing import Any

import lightning as L
import torch
from lightning.pytorch.callbacks import Callback
from lightning.pytorch.utilities.exceptions import MisconfigurationException
from torch import nn

from spade.utils.errors import ConfigError
from spade.utils.hardware import bf16_fast
from spade.training.callbacks import ChannelsLast

#: Lightning's precision values (``lightning.pytorch.Trainer(precision=...)``), plus ``auto``.
PRECISIONS: tuple[str, ...] = ("auto", "64-true", "32-true", "16-mixed", "bf16-mixed", "16-true", "bf16-true",
                               "64", "32", "16", "bf16", "transformer-engine", "transformer-engine-float16")


def _accelerator_kind(accelerator: Any) -> str:
    """``cpu`` or ``gpu`` for an accelerator flag (``auto``: a GPU when CUDA has one)."""
    name = str(accelerator).lower()
    if name in ("gpu", "cuda"):
        return "gpu"
    if name == "auto":
        return "gpu" if torch.cuda.is_available() else "cpu"
    return "cpu" if name == "cpu" else name


def resolve_precision(precision: Any, accelerator: Any = "auto") -> str | int:
    """``trainer.precision`` for Lightning: ``auto`` becomes ``bf16-mixed`` where bf16 is native
    (:func:`~spade.utils.hardware.bf16_fast`), else ``32-true``; other values are checked and passed on."""
    if isinstance(precision, int) and not isinstance(precision, bool):
        precision = str(precision)
    if precision not in PRECISIONS:
        raise ConfigError(f"trainer.precision={precision!r} is not a precision; use one of {', '.join(PRECISIONS)} "
                          "(auto: bf16-mixed where the CPU or GPU has native bf16, else 32-true)")
    if precision == "auto":
        return "bf16-mixed" if bf16_fast(_accelerator_kind(accelerator)) else "32-true"
    return precision


def _switch(key: str, value: Any) -> bool | str:
    if isinstance(value, str) and value.lower() in ("true", "false", "auto"):
        value = {"true": True, "false": False}.get(value.lower(), "auto")
    if not (isinstance(value, bool) or value == "auto"):
        raise ConfigError(f"trainer.{key}={value!r} must be true, false or auto")
    return value


def resolve_channels_last(value: Any, accelerator: Any = "auto") -> bool:
    """``trainer.channels_last``: ``auto`` is on where NHWC convolutions are native (oneDNN on a CPU, cuDNN on a
    GPU); ``true``/``false`` as given."""
    value = _switch("channels_last", value)
    if value != "auto":
        return bool(value)
    if _accelerator_kind(accelerator) == "gpu":
        return True
    return bool(torch.backends.mkldnn.is_available())


class Bf16Module(nn.Module):
    """A frozen module held and run in bf16: floating inputs cast to bf16, outputs back to the caller's dtype.

    Casts of the owner (``.to(torch.float32)``, ``.double()``) move it but keep it in bf16: a frozen network has no
    master weights to keep in fp32, and gradients still flow through it to its inputs."""

    def __init__(self, inner: nn.Module) -> None:
        super().__init__()
        self.inner = inner.to(torch.bfloat16)

    def _apply(self, fn: Any, recurse: bool = True) -> Bf16Module:
        super()._apply(fn, recurse)
        self.inner.to(torch.bfloat16)
        return self

    def forward(self, *args: Any) -> Any:
        dtype = next((a.dtype for a in args if isinstance(a, torch.Tensor) and a.is_floating_point()), None)
        cast = [a.to(torch.bfloat16) if isinstance(a, torch.Tensor) and a.is_floating_point() else a for a in args]
        with torch.autocast(args[0].device.type, enabled=False):
            out = self.inner(*cast)
        return out.to(dtype) if dtype is not None else out


def use_bf16_expert(module: nn.Module) -> bool:
    """Hold the margin's frozen expert of a student ``module`` in bf16 (:class:`Bf16Module`); False when the
    module has no margin (BC, an expert) or it already is."""
    margin = getattr(module, "margin", None)
    expert = getattr(margin, "expert", None)
    if expert is None or isinstance(expert, Bf16Module):
        return False
    margin.expert = Bf16Module(expert)
    return True


def speed_callbacks(channels_last: bool, callbacks: list[Callback]) -> list[Callback]:
    """The callbacks the resolved options need that ``callbacks`` does not hold yet."""
    if channels_last and not any(isinstance(c, ChannelsLast) for c in callbacks):
        return [ChannelsLast()]
    return []


def build_trainer(*, precision: Any = "32-true", channels_last: Any = "auto",
                  callbacks: list[Callback] | Callback | None = None, accelerator: Any = "auto",
                  **kwargs: Any) -> L.Trainer:
    """A :class:`lightning.pytorch.Trainer` with the speed options resolved (module docstring); ``kwargs`` are
    Lightning's."""
    callbacks = [callbacks] if isinstance(callbacks, Callback) else list(callbacks or [])
    callbacks += speed_callbacks(resolve_channels_last(channels_last, accelerator), callbacks)
    precision = resolve_precision(precision, accelerator)
    try:
        return L.Trainer(accelerator=accelerator, precision=precision, callbacks=callbacks, **kwargs)
    except (MisconfigurationException, ValueError, TypeError, ImportError) as exc:  # Lightning refuses an option
        given = {"accelerator": accelerator, **{k: kwargs[k] for k in ("devices", "strategy", "num_nodes") if k in kwargs}}
        raise ConfigError(f"trainer ({', '.join(f'trainer.{k}={v}' for k, v in given.items())}): "
                          f"{' '.join(str(exc).split())}; fix the trainer option it names (e.g. trainer.accelerator=cpu, "
                          "trainer.devices=1)") from exc
