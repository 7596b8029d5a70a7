"""The verdict of a closed loop: how the student drove, and the student against each classical planner driven
through the same scenarios (``closed_loop/*``, :mod:`spade.metrics.closed_loop`).

The figure that decides is the closed-loop APE (``closed_loop/ape_cm``: the executed path against the whole
demonstration; a failure's partial path scores what it missed) with the success rate beside it, as the open-loop
verdict (:mod:`spade.metrics.verdict`) reads the planner's APE with its tail: the student *beats* a planner when its
APE is lower and its success rate no lower, *loses to* it when its APE is higher and its success rate no higher, and
is *mixed against* it otherwise (then both success rates are named). The demonstration given to the follower
(``closed_loop/followed/``) is named last: what the follower itself costs, the APE no planner can expect to pass.

One run's figures, without seeds: a comparison between models needs seeds and a test (the closed-loop page).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

from spade.metrics import catalog
from spade.metrics.baselines import BASELINES
from spade.metrics.catalog import BASELINE_LABELS
from spade.metrics.verdict import finite_value

__all__ = ["ClosedLoopVerdict", "closed_loop_verdict", "closed_loop_verdicts"]

APE = "ape_cm"
SUCCESS = "success_rate"
OUTCOMES = ("beats", "mixed against", "loses to", "matches")  # the order a sentence names them in
VERBS = {"beats": "beats", "mixed against": "is mixed against", "loses to": "loses to", "matches": "matches"}


def _cm(value: float) -> str:
    return f"{catalog.fmt(f'closed_loop/{APE}', value, compact=True)} cm"


def _share(value: float) -> str:
    return f"{catalog.fmt(f'closed_loop/{SUCCESS}', value, compact=True)} %"


def _listed(items: list[str], last: str = " and ") -> str:
    """``a``, ``a and b``, ``a, b and c`` (``last`` between the last two items)."""
    return items[0] if len(items) == 1 else ", ".join(items[:-1]) + last + items[-1]


@dataclass(frozen=True)
class ClosedLoopVerdict:
    """The student against one planner driven in closed loop: (student, planner) APE in cm and success rate."""

    baseline: str
    outcome: str  # one of OUTCOMES
    ape: tuple[float, float]
    success: tuple[float, float]

    def figures(self) -> str:
        """The planner's figures as a sentence names them: its APE, and its success rate where it differs."""
        if self.outcome == "mixed against" or self.success[0] != self.success[1]:
            return f"{_cm(self.ape[1])}, success {_share(self.success[1])}"
        return _cm(self.ape[1])


def closed_loop_verdicts(metrics: Mapping[str, float]) -> list[ClosedLoopVerdict]:
    """The student's verdict against each baseline driven in closed loop (``closed_loop/baseline/<name>/``) that
    has an APE and a success rate, as the student has (see the module); empty when the student was not driven."""
    own = finite_value(metrics, f"closed_loop/{APE}"), finite_value(metrics, f"closed_loop/{SUCCESS}")
    if None in own:
        return []
    out = []
    for name in BASELINES:
        prefix = f"closed_loop/baseline/{name}/"
        base = finite_value(metrics, prefix + APE), finite_value(metrics, prefix + SUCCESS)
        if None in base:
            continue
        ape, success = (own[0], base[0]), (own[1], base[1])
        if ape[0] == ape[1] and success[0] == success[1]:
            outcome = "matches"
        elif ape[0] <= ape[1] and success[0] >= success[1]:
            outcome = "beats"
        elif ape[0] >= ape[1] and success[0] <= success[1]:
            outcome = "loses to"
        else:
            outcome = "mixed against"
        out.append(ClosedLoopVerdict(name, outcome, ape, success))  # type: ignore[arg-type]
    return out


def closed_loop_verdict(metrics: Mapping[str, float], model: str = "the student") -> str | None:
    """One sentence: the student's success rate, APE and mode switches per scenario, then the verdict against the
    planners it was driven against (:func:`closed_loop_verdicts`), then what the followed demonstration drives at;
    None when the run drove nothing in closed loop."""
    ape, success = finite_value(metrics, f"closed_loop/{APE}"), finite_value(metrics, f"closed_loop/{SUCCESS}")
    if ape is None or success is None:
        return None
    text = f"success {_share(success)}, APE {_cm(ape)}"
    switches = finite_value(metrics, "closed_loop/mode_switches")
    if switches is not None:
        text += f", {catalog.fmt('closed_loop/mode_switches', switches)} mode switches per scenario"
    found = closed_loop_verdicts(metrics)
    groups = []
    for outcome in OUTCOMES:
        named = [f"the {BASELINE_LABELS.get(v.baseline, v.baseline)} ({v.figures()})" for v in found
                 if v.outcome == outcome]
        if named:
            groups.append(f"{VERBS[outcome]} " + _listed(named))
    if groups:
        text += f"; {model} " + (" but ".join(groups) if len(groups) == 2 else _listed(groups, ", and "))
    else:
        text += "; no classical planner was driven beside it"
    followed = finite_value(metrics, f"closed_loop/followed/{APE}")
    if followed is not None:
        text += f"; the demonstration followed drives at {_cm(followed)} (what the follower itself costs)"
    return text
