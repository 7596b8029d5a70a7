"""The results pages' one statistics kernel: the tests (Welch's, paired, one-sample), Holm's correction and the
``mean ± sd`` cell.

Every results page (the paper tables, the closed-loop, teacher and oracle pages, the perf pages) tests and
summarises its seeds here, so that one comparison reads the same wherever it is printed. All tests are two-sided,
at :data:`ALPHA`; a test that cannot be computed (fewer than two values on a side, no spread) gives ``None``, never
a p-value of a degenerate sample.
"""

from __future__ import annotations

import math
import statistics
import warnings
from collections.abc import Callable, Sequence

__all__ = ["ALPHA", "NO_TEST", "holm", "mean_sd", "one_sample", "paired", "significance", "welch"]

ALPHA = 0.05  # significance level of every two-sided test of the pages
NO_TEST = "n=1, no test"

Format = Callable[[float], str] | str
"""How a figure is written: a format spec (``".2f"``) or a function of the value."""


def _pvalue(test: Callable[[], object]) -> float | None:
    """The test's p-value; None when scipy returns NaN (nearly constant samples: it warns, silenced here)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        p = float(test().pvalue)  # type: ignore[attr-defined]
    return None if math.isnan(p) else p


def welch(a: Sequence[float], b: Sequence[float]) -> tuple[float | None, str]:
    """Welch's two-sided t-test of ``a`` against ``b`` (``scipy.stats.ttest_ind(equal_var=False)``): ``(p,
    wording)``; ``(None, "n=1, no test")`` with fewer than two values on either side, ``(None, "no test (no
    spread)")`` when both sides are constant."""
    if len(a) < 2 or len(b) < 2:
        return None, NO_TEST
    if statistics.pvariance(a) == 0 and statistics.pvariance(b) == 0:
        return None, "no test (no spread)"
    from scipy.stats import ttest_ind

    p = _pvalue(lambda: ttest_ind(a, b, equal_var=False))
    if p is None:
        return None, "no test (no spread)"
    return p, f"p = {p:.3g}" + ("" if p < ALPHA else ", not significant")


def paired(a: Sequence[float], b: Sequence[float]) -> float | None:
    """The two-sided paired t-test's p of ``a`` against ``b`` (``a[i]`` paired with ``b[i]``); None with fewer than
    two pairs or when the differences have no spread."""
    if len(a) < 2 or statistics.pvariance([x - y for x, y in zip(a, b)]) == 0:
        return None
    from scipy.stats import ttest_rel

    return _pvalue(lambda: ttest_rel(a, b))


def one_sample(values: Sequence[float], value: float) -> float | None:
    """The two-sided one-sample t-test's p of ``values`` against ``value``; None with fewer than two values or no
    spread."""
    if len(values) < 2 or statistics.pstdev(values) == 0:
        return None
    from scipy.stats import ttest_1samp

    return _pvalue(lambda: ttest_1samp(values, value))


def holm(p_values: Sequence[float | None]) -> list[float | None]:
    """Holm's step-down adjustment of a family of p-values (None: no test, left out of the family and kept None):
    the i-th smallest of m is multiplied by (m - i), made monotone and capped at 1. A test is significant at
    :data:`ALPHA` after the correction when its adjusted p is below it."""
    tested = sorted((p, i) for i, p in enumerate(p_values) if p is not None)
    out: list[float | None] = [None] * len(p_values)
    running = 0.0
    for rank, (p, i) in enumerate(tested):
        running = max(running, min(1.0, (len(tested) - rank) * p))
        out[i] = running
    return out


def significance(p: float | None) -> str:
    """A (Holm-adjusted) p in words: ``significant``, ``not significant`` or ``no test``."""
    return "no test" if p is None else ("significant" if p < ALPHA else "not significant")


def _written(fmt: Format, value: float) -> str:
    return fmt(value) if callable(fmt) else format(value, fmt)


def mean_sd(values: Sequence[float], fmt: Format = ".2f", sd_fmt: Format | None = None, empty: str = "n/a",
            sep: str = " ± ") -> str:
    """``mean ± sd`` of ``values`` (the sample sd, ``ddof=1``), each written by ``fmt`` (the sd by ``sd_fmt`` when
    given); the value alone for one value, ``empty`` for none."""
    if not values:
        return empty
    if len(values) == 1:
        return _written(fmt, values[0])
    spread = statistics.stdev(values)
    return f"{_written(fmt, statistics.fmean(values))}{sep}{_written(sd_fmt or fmt, spread)}"
