"""What the machine's arithmetic units can do fast, detected (never guessed): bf16 on the CPU or the GPU.

A CPU runs bf16 convolutions and matmuls faster than fp32 only with native bf16 instructions (AVX-512 BF16 or
AMX, ``/proc/cpuinfo`` flags ``avx512_bf16`` / ``amx_bf16``); without them oneDNN emulates bf16 and a step gets
slower. ``torch.backends.cpu.get_cpu_capability()`` names the vector ISA torch dispatches to (``AVX512``,
``AVX2``, ...) but not whether that ISA has the bf16 extension, hence the flags.
"""

from __future__ import annotations

import functools

import torch

#: /proc/cpuinfo flags of native bf16 arithmetic on x86 CPUs.
BF16_CPU_FLAGS: tuple[str, ...] = ("avx512_bf16", "amx_bf16")


@functools.lru_cache(maxsize=1)
def cpu_flags() -> frozenset[str]:
    """The CPU's feature flags (``/proc/cpuinfo``); empty where there is none (macOS, Windows)."""
    try:
        with open("/proc/cpuinfo") as handle:
            for line in handle:
                if line.startswith(("flags", "Features")):
                    return frozenset(line.split(":", 1)[1].split())
    except OSError:  # pragma: no cover - non-Linux
        pass
    return frozenset()


def cpu_capability() -> str:
    """The vector ISA torch's CPU kernels dispatch to (``AVX512``, ``AVX2``, ``DEFAULT``, ...)."""
    try:
        return str(torch.backends.cpu.get_cpu_capability())
    except AttributeError:  # pragma: no cover - torch < 2.1
        return "unknown"


def cpu_has_bf16() -> bool:
    """Whether the CPU has native bf16 arithmetic (AVX-512 BF16 or AMX)."""
    return any(flag in cpu_flags() for flag in BF16_CPU_FLAGS)


def bf16_fast(accelerator: str) -> bool:
    """Whether bf16 autocast can pay on ``accelerator`` (``cpu``, ``gpu``/``cuda``; ``auto``: a GPU if there is one):
    a CUDA device that supports bf16 (Ampere and newer), or a CPU with native bf16 arithmetic."""
    accelerator = str(accelerator).lower()
    if accelerator in ("gpu", "cuda") or (accelerator == "auto" and torch.cuda.is_available()):
        return torch.cuda.is_available() and torch.cuda.is_bf16_supported()
    if accelerator in ("cpu", "auto"):
        return cpu_has_bf16()
    return False


def describe() -> dict[str, object]:
    """The detected facts behind the ``auto`` settings (for the bench's page and logs)."""
    return {"cpu_capability": cpu_capability(), "cpu_bf16": cpu_has_bf16(),
            "cpu_bf16_flags": sorted(f for f in BF16_CPU_FLAGS if f in cpu_flags()),
            "cuda_bf16": bool(torch.cuda.is_available() and torch.cuda.is_bf16_supported()),
            "mkldnn": bool(torch.backends.mkldnn.is_available())}
