"""95 % intervals from a bootstrap over test scenarios: what a small test set can and cannot tell.

A test set's instances are not independent: the states of one scenario (one demonstrated manoeuvre) are
near-duplicates, so an interval from instances alone would be far too narrow. The bootstrap here resamples whole
scenarios (a cluster bootstrap) and recomputes the mean over the instances of the drawn scenarios. Seeds are pooled
within a scenario (each scenario's instances of every seed), so the interval is over test scenarios, the seeds'
spread being reported beside it (mean +/- sd). :func:`paired_difference` compares two predictors scenario by
scenario on the same test set: significant when its interval excludes 0.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = ["Interval", "scenario_interval", "paired_difference", "BOOTSTRAP_DRAWS"]

BOOTSTRAP_DRAWS = 2000
SEED = 0


@dataclass(frozen=True)
class Interval:
    """A mean with its 95 % bootstrap interval over ``scenarios`` test scenarios (``instances`` values)."""

    mean: float
    low: float
    high: float
    scenarios: int
    instances: int

    def excludes_zero(self) -> bool:
        return self.low > 0 or self.high < 0

    def format(self, spec: str = ".2f", percent: bool = False) -> str:
        if math.isnan(self.mean):
            return "n/a"
        if percent:
            return f"{100 * self.mean:.0f} % [{100 * self.low:.0f}, {100 * self.high:.0f}]"
        return f"{self.mean:{spec}} [{self.low:{spec}}, {self.high:{spec}}]"


def _by_scenario(scenarios: Sequence[str], values: Sequence[float]) -> tuple[np.ndarray, np.ndarray, int]:
    """Per-scenario sums and counts of the finite values, and how many values counted."""
    sums: dict[str, float] = {}
    counts: dict[str, int] = {}
    n = 0
    for s, v in zip(scenarios, values):
        if v is None or not math.isfinite(float(v)):
            continue
        sums[s] = sums.get(s, 0.0) + float(v)
        counts[s] = counts.get(s, 0) + 1
        n += 1
    keys = sorted(sums)
    return np.array([sums[k] for k in keys]), np.array([counts[k] for k in keys], dtype=float), n


def scenario_interval(scenarios: Sequence[str], values: Sequence[float], draws: int = BOOTSTRAP_DRAWS,
                      seed: int = SEED) -> Interval:
    """The mean of ``values`` (NaN ones left out: a failure is scored by the figures that count it) with a 95 %
    percentile interval from resampling the scenarios (``scenarios[i]`` is value i's) with replacement."""
    sums, counts, n = _by_scenario(scenarios, values)
    if n == 0:
        return Interval(float("nan"), float("nan"), float("nan"), 0, 0)
    mean = float(sums.sum() / counts.sum())
    if len(sums) < 2:
        return Interval(mean, float("nan"), float("nan"), len(sums), n)
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(sums), size=(draws, len(sums)))
    boot = sums[idx].sum(1) / counts[idx].sum(1)
    low, high = np.percentile(boot, [2.5, 97.5])
    return Interval(mean, float(low), float(high), len(sums), n)


def paired_difference(a: dict[str, list[float]], b: dict[str, list[float]], draws: int = BOOTSTRAP_DRAWS,
                      seed: int = SEED) -> Interval:
    """Mean of (a - b) over the scenarios both have, each scenario's value the mean of its instances (all seeds),
    with a 95 % interval from resampling those scenarios: ``a`` and ``b`` map scenario -> values."""
    keys = sorted(k for k in set(a) & set(b) if _finite(a[k]) and _finite(b[k]))
    if not keys:
        return Interval(float("nan"), float("nan"), float("nan"), 0, 0)
    diff = np.array([np.mean(_finite(a[k])) - np.mean(_finite(b[k])) for k in keys])
    if len(diff) < 2:
        return Interval(float(diff.mean()), float("nan"), float("nan"), len(diff), len(diff))
    rng = np.random.default_rng(seed)
    boot = diff[rng.integers(0, len(diff), size=(draws, len(diff)))].mean(1)
    low, high = np.percentile(boot, [2.5, 97.5])
    return Interval(float(diff.mean()), float(low), float(high), len(diff), len(diff))


def _finite(values: list[float]) -> list[float]:
    return [float(v) for v in values if v is not None and math.isfinite(float(v))]
