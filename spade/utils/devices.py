"""The one device policy of SPADE's model runners, without torch (the deploy install's ONNX runner uses it too)."""

from __future__ import annotations

import re

__all__ = ["device_name"]


def device_name(device: object, cuda_available: bool, error: type[Exception], no_cuda: str) -> str:
    """``cpu``, ``cuda`` / ``cuda:N`` (``error`` when there is no CUDA: ``no_cuda`` says why and the fix), or
    ``auto`` (CUDA when available, else the CPU); anything else is ``error``."""
    name = str(device or "cpu").lower()
    if name == "auto":
        return "cuda" if cuda_available else "cpu"
    if name == "cpu":
        return name
    if re.fullmatch(r"cuda(:\d+)?", name):
        if not cuda_available:
            raise error(f"device={device} asked for, but {no_cuda}")
        return name
    raise error(f"unknown device {device!r}: use cpu, cuda, cuda:N or auto")
