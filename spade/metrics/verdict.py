"""The verdict of a test: which figure decides, and the model against every classical baseline by it.

A learned planner is worth deploying where it beats what needs no learning. The figure that decides is the
planner's (the path a robot drives, decoded by search), in this order:

1. ``planner/ape_cm`` with its tail ``planner/over_20cm_rate`` (failures count in the tail): the model *beats* a
   baseline when its APE is lower and its tail no longer, *loses* when its APE is higher and its tail no shorter,
   and is *mixed* otherwise (then the tail is named: a mean hides broken paths);
2. where the test set has alternative demonstrations, ``planner/plausibility_cm`` and ``planner/commit_rate``
   (:mod:`spade.metrics.preference`): a path nearer to one an operator could have drawn, committed to one way of
   turning, is the preference SPADE is for; they are reported beside the APE verdict, and a disagreement (lower APE
   but less plausible) is said in words, with ``planner/ape_over_floor``: how far the APE still is from the floor
   that no predictor can pass.

The figures are one test's, without seeds: a comparison between models needs seeds and a test
(``spade.report``); this says how one model did against the baselines on the same instances.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

from spade.metrics import catalog
from spade.metrics.baselines import BASELINES
from spade.metrics.catalog import BASELINE_LABELS

DECIDING_FIGURE = "planner/ape_cm"
TAIL_FIGURE = "planner/over_20cm_rate"
PREFERENCE_FIGURES = ("planner/plausibility_cm", "planner/commit_rate")

__all__ = ["DECIDING_FIGURE", "Verdict", "verdicts", "verdict_lines"]


def finite_value(metrics: Mapping[str, float], key: str) -> float | None:
    """``metrics[key]`` as a float; None when it is missing or NaN (a figure that cannot be compared)."""
    value = metrics.get(key)
    if value is None:
        return None
    value = float(value)
    return None if math.isnan(value) else value


@dataclass(frozen=True)
class Verdict:
    """The model against one baseline."""

    baseline: str
    outcome: str  # "beats" | "loses to" | "mixed against" | "cannot be compared with"
    ape: tuple[float, float] | None  # (model, baseline) planner APE, cm
    tail: tuple[float, float] | None  # (model, baseline) share over 20 cm
    plausibility: tuple[float, float] | None = None  # (model, baseline), cm
    commit: tuple[float, float] | None = None  # (model, baseline)

    def sentence(self, model: str = "the model") -> str:
        label = BASELINE_LABELS.get(self.baseline, self.baseline)
        if self.ape is None:
            return f"{model} {self.outcome} the {label}: no planner APE for one of them"
        text = (f"{model} {self.outcome} the {label} by the planner's APE and tail "
                f"({self.ape[0]:.2f} vs {self.ape[1]:.2f} cm")
        if self.tail is not None:
            tail = catalog.label(TAIL_FIGURE, qualified=False)
            text += f"; {tail} {100 * self.tail[0]:.0f} % vs {100 * self.tail[1]:.0f} %"
        text += ")"
        if self.plausibility is not None:
            text += (f"; plausibility {self.plausibility[0]:.2f} vs {self.plausibility[1]:.2f} cm")
            if self.commit is not None:
                text += f", commits {100 * self.commit[0]:.0f} % vs {100 * self.commit[1]:.0f} %"
            nearer = self.plausibility[0] < self.plausibility[1]
            if self.outcome == "beats" and not nearer:
                text += " (lower APE, but farther from any path an operator drew)"
            elif self.outcome == "loses to" and nearer:
                text += " (higher APE, but nearer to a path an operator drew)"
        return text


def verdicts(metrics: Mapping[str, float], prefix: str = "test") -> list[Verdict]:
    """The model's verdict against each baseline logged under ``{prefix}/baseline/<name>/`` (see the module)."""
    out = []
    for name in BASELINES:
        base = f"{prefix}/baseline/{name}/"
        if not any(k.startswith(base) for k in metrics):
            continue
        ape = (finite_value(metrics, f"{prefix}/{DECIDING_FIGURE}"), finite_value(metrics, base + DECIDING_FIGURE))
        tail = (finite_value(metrics, f"{prefix}/{TAIL_FIGURE}"), finite_value(metrics, base + TAIL_FIGURE))
        plaus = (finite_value(metrics, f"{prefix}/{PREFERENCE_FIGURES[0]}"), finite_value(metrics, base + PREFERENCE_FIGURES[0]))
        commit = (finite_value(metrics, f"{prefix}/{PREFERENCE_FIGURES[1]}"), finite_value(metrics, base + PREFERENCE_FIGURES[1]))
        has_tail = None not in tail
        if None in ape:
            outcome = "cannot be compared with"
        elif ape[0] < ape[1] and (not has_tail or tail[0] <= tail[1]):
            outcome = "beats"
        elif ape[0] > ape[1] and (not has_tail or tail[0] >= tail[1]):
            outcome = "loses to"
        else:
            outcome = "mixed against"
        out.append(Verdict(name, outcome, None if None in ape else ape,  # type: ignore[arg-type]
                           tail if has_tail else None,  # type: ignore[arg-type]
                           None if None in plaus else plaus,  # type: ignore[arg-type]
                           None if None in commit else commit))  # type: ignore[arg-type]
    return out


def verdict_lines(metrics: Mapping[str, float], prefix: str = "test", model: str = "the model",
                  with_floor: bool = True) -> list[str]:
    """The verdict as lines of text: the deciding figure named, the floor and the BC ceiling where known
    (``with_floor``: False where the text says them already, as a closing summary does), one line per baseline."""
    found = verdicts(metrics, prefix)
    if not found:
        return []
    lines = [f"deciding figure: the planner's APE ({DECIDING_FIGURE}) with its tail ({TAIL_FIGURE}), then "
             "plausibility and commitment where the test set has alternatives"]
    if not with_floor:
        return lines + [v.sentence(model) for v in found]
    floor, ratio = finite_value(metrics, f"{prefix}/floor_cm"), finite_value(metrics, f"{prefix}/planner/ape_over_floor")
    if floor is not None and ratio is not None:
        lines.append(f"floor: {floor:.2f} cm (the best a single path can do against one demonstration); "
                     f"{model}'s planner APE is {ratio:.2f}x it")
    ceiling = finite_value(metrics, f"{prefix}/ceiling/planner/ape_cm")
    ceiling_ratio = finite_value(metrics, f"{prefix}/ceiling/planner/ape_over_floor")
    if ceiling is not None and ceiling_ratio is not None:
        lines.append(f"BC ceiling: {ceiling:.2f} cm, {ceiling_ratio:.2f}x the floor (the plausible set's mean image, "
                     "what a perfect BC student converges to, decoded by the planner)")
    lines += [v.sentence(model) for v in found]
    return lines
