"""Training step time of BC, DBC and Cond-DBC with the same student, batch and optimiser.

A step is what Lightning runs per batch minus its bookkeeping: ``StudentModule.losses`` (BCE, plus the diffusion
margin of a frozen expert for DBC / Cond-DBC), backward, AdamW step. The experts are fresh
:class:`~spade.training.expert_module.ExpertModule` s with random weights (their cost does not depend on them),
wired into the student exactly as ``StudentModule.load_margin`` wires a trained one (``StudentModule.use_expert``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import torch

from spade.utils.timing import step_time


def student_with_margin(size: str, expert: str | None = None, preset: str = "tiny", **margin: Any) -> Any:
    """A :class:`StudentModule` of ``size``; with the diffusion margin (``margin``: :class:`MarginConfig` options)
    of a fresh ``cond``/``uncond`` expert of ``preset`` if given."""
    from spade.training.expert_module import ExpertModule
    from spade.training.margin import MarginConfig
    from spade.training.student_module import StudentModule

    module = StudentModule(size=size)
    if expert is not None:
        if expert not in ("cond", "uncond"):
            raise ValueError(f"expert must be 'cond' or 'uncond', got {expert!r}")
        # the default noise schedule (1000 steps, epsilon); no metrics: the module only lends its denoiser
        expert_module = ExpertModule(conditional=expert == "cond", preset=preset,
                                     metrics={"fid": False, "planner": False})
        module.margin_cfg = MarginConfig(**margin)
        module.use_expert(expert_module, source=f"the {expert} expert")
        del expert_module  # the margin keeps the EMA denoiser, not the module's training weights
    return module.train()


def training_step_times(student: str, image_size: int, batch_size: int, cond_presets: Sequence[str],
                        uncond_preset: str | None, runs: int = 3, warmup: int = 1,
                        batched_terms: bool = True) -> list[dict[str, Any]]:
    """Step time of BC, DBC (unconditional expert of ``uncond_preset``), Cond-DBC with each conditional expert
    preset and, with ``batched_terms``, Cond-DBC with ``batch_terms=True`` (one expert forward over
    [agent; expert]) for the first preset; each with its ratio to BC."""
    from spade.deploy.export import example_states

    torch.manual_seed(0)
    state = example_states(batch_size, (image_size, image_size), seed=0)
    path = (torch.rand(batch_size, 1, image_size, image_size) > 0.97).float()
    batch = {"state": state, "path": path}
    setups: list[tuple[str, str | None, str | None, dict]] = [("BC", None, None, {})]
    if uncond_preset:
        setups.append(("DBC", "uncond", uncond_preset, {}))
    setups += [("Cond-DBC", "cond", preset, {}) for preset in cond_presets]
    if batched_terms and cond_presets:
        setups.append(("Cond-DBC (batch_terms)", "cond", cond_presets[0], {"batch_terms": True}))
    rows = []
    for name, expert, preset, options in setups:
        module = student_with_margin(student, expert, preset or "tiny", **options)
        row = {"approach": name, "student": student, "expert_preset": preset, "image_size": image_size,
               "batch_size": batch_size, **step_time(module, batch, runs, warmup)}
        rows.append(row)
        del module
    bc = rows[0]["step_ms"]
    for row in rows:
        row["ratio_to_bc"] = row["step_ms"] / bc
    return rows
