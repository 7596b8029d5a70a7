"""The oracle page's data-size curve: BC and the best guided row at several numbers of site demonstrations, between
the floor and the BC ceiling (``curve:`` in ``conf/report.yaml``'s ``oracle`` block).

At each size every series is tested against the first series (BC) at the same size, with the page's rule: Welch's
test over seeds (Holm's correction over every test of the page) and the paired bootstrap over scenarios must both tell
them apart. The chart (``<page>_curve.png``) draws each series' mean over seeds with its sd, and the floor, the BC
ceiling and the best non-learned baseline as horizontal lines.
"""

from __future__ import annotations

import statistics
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from spade.experiments.reporting.intervals import paired_difference
from spade.experiments.reporting.stats import mean_sd, welch
from spade.experiments.run_records import RunRecord
from spade.deploy.outputs import SOFTWARE

__all__ = ["CurveSeries", "curve_series", "curve_tests", "curve_section", "curve_rows", "plot_curve"]

DECIDING = "test/planner/ape_cm"

CurveSeries = dict[str, dict[int, str]]
"""series label -> {number of demonstrations -> run name}."""


def curve_series(settings: Mapping[str, Any] | None) -> CurveSeries:
    """The ``curve:`` setting as {label: {size: row}}, sizes as ints; a clear error for a malformed one."""
    out: CurveSeries = {}
    for label, points in dict(settings or {}).items():
        if not isinstance(points, Mapping):
            raise ValueError(f"oracle.curve.{label} must map a number of demonstrations to a run name, e.g. "
                             "{250: site_bc_250_L, 500: site_bc_L}")
        try:
            out[str(label)] = {int(size): str(row) for size, row in points.items()}
        except (TypeError, ValueError) as exc:
            raise ValueError(f"oracle.curve.{label}: a size that is not a whole number ({exc}); write sizes as "
                             "numbers of demonstrations, e.g. 250") from exc
    return out


def curve_rows(series: CurveSeries) -> set[str]:
    """Every run name the curve reads."""
    return {row for points in series.values() for row in points.values()}


def _values(runs: list[RunRecord]) -> list[float]:
    return [r.metrics[DECIDING] for r in runs if DECIDING in r.metrics]


def _by_scenario(runs: list[RunRecord]) -> dict[str, list[float]]:
    out: dict[str, list[float]] = {}
    for r in runs:
        for i in r.instances:
            value = i.get("planner_ape_cm")
            out.setdefault(str(i.get("scenario", "")), []).append(float("nan") if value in (None, "") else float(value))
    return out


def curve_tests(series: CurveSeries, runs: Mapping[str, list[RunRecord]],
                known: Mapping[tuple[str, str], dict[str, Any]] | None = None) -> dict[tuple[str, int], dict[str, Any]]:
    """(series, size) -> Welch's p and the paired bootstrap against the first series at the same size. A pair of runs
    the page already tests (``known``, keyed (row, against)) reuses that test, so that one comparison has one
    verdict; the caller applies Holm's correction over the page's whole family."""
    labels = list(series)
    if len(labels) < 2:
        return {}
    base = series[labels[0]]
    out: dict[tuple[str, int], dict[str, Any]] = {}
    for label in labels[1:]:
        for size, row in series[label].items():
            if size not in base or not runs.get(row) or not runs.get(base[size]):
                continue
            if known and (row, base[size]) in known:
                out[(label, size)] = known[(row, base[size])]
                continue
            a, b = runs[row], runs[base[size]]
            p, _ = welch(_values(a), _values(b))
            sa, sb = _by_scenario(a), _by_scenario(b)
            out[(label, size)] = {"p": p, "paired": paired_difference(sa, sb) if sa and sb else None}
    return out


def _seeds_cell(values: list[float]) -> str:
    """The series' planner APE over its seeds, with their count (``not run`` without one)."""
    if not values:
        return "not run"
    return mean_sd(values) + f" ({len(values)} seed{'s' if len(values) > 1 else ''})"


def curve_section(series: CurveSeries, runs: Mapping[str, list[RunRecord]],
                  tests: dict[tuple[str, int], dict[str, Any]], floor: float | None, ceiling: float | None,
                  significant: Callable[[dict[str, Any]], bool]) -> tuple[list[str], list[str]]:
    """(the section's markdown lines, the verdict's sentences) of the curve; empty when no point has a run."""
    if not any(runs.get(row) for points in series.values() for row in points.values()):
        return [], []
    sizes = sorted({s for points in series.values() for s in points})
    labels = list(series)
    base = series[labels[0]]
    lines = ["| series | " + " | ".join(f"{s:,} demonstrations" for s in sizes) + " |",
             "|---|" + "---|" * len(sizes)]
    for label in labels:
        cells = []
        for size in sizes:
            row = series[label].get(size)
            cell = _seeds_cell(_values(runs.get(row, []))) if row else "—"
            test = tests.get((label, size))
            base_values = _values(runs.get(base.get(size, ""), []))
            if test is not None and base_values and row:
                diff = statistics.fmean(_values(runs[row])) - statistics.fmean(base_values)
                holm_p = test.get("holm")
                one_seed = len(_values(runs[row])) < 2 or len(base_values) < 2
                told = "one seed" if one_seed else "told apart" if significant(test) else "not told apart"
                cell += f" <br>{diff:+.2f} cm, {told}" + ("" if holm_p is None else f" (Holm p {holm_p:.2g})")
            cells.append(cell)
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    if floor is not None:
        lines.append("| floor | " + " | ".join(f"{floor:.2f}" for _ in sizes) + " |")
    if ceiling is not None:
        lines.append("| BC ceiling | " + " | ".join(f"{ceiling:.2f}" for _ in sizes) + " |")
    verdict = []
    for size in sizes:
        bc = _values(runs.get(base.get(size, ""), []))
        if not bc:
            continue
        bc_mean = statistics.fmean(bc)
        text = f"at {size:,} demonstrations {labels[0]} plans at {bc_mean:.2f} cm"
        if ceiling is not None:
            text += f" ({bc_mean - ceiling:+.2f} cm from the ceiling)"
        parts = []
        for label in labels[1:]:
            test = tests.get((label, size))
            values = _values(runs.get(series[label].get(size, ""), []))
            if test is None or not values:
                continue
            mean = statistics.fmean(values)
            gap = "" if ceiling is None or bc_mean - ceiling <= 0 else \
                f", {100 * (bc_mean - mean) / (bc_mean - ceiling):.0f} % of the gap"
            if len(values) < 2 or len(bc) < 2:  # one training seed: its difference may be the seed's
                told = "one seed, not tested over seeds"
            else:
                told = "told apart" if significant(test) else "not told apart"
            parts.append(f"{label} {mean:.2f} cm ({mean - bc_mean:+.2f}{gap}; {told})")
        verdict.append(text + (": " + "; ".join(parts) if parts else ""))
    sentences = ["- **Data-size curve**: " + "; ".join(verdict) + "."] if verdict else []
    return lines, sentences


def plot_curve(series: CurveSeries, runs: Mapping[str, list[RunRecord]], floor: float | None, ceiling: float | None,
               baseline: tuple[str, float] | None, path: Path) -> None:
    """Planner APE against the number of demonstrations (log axis), one line per series with its sd over seeds, the
    floor, the BC ceiling and the best baseline drawn across."""
    from matplotlib.figure import Figure  # not pyplot: no global state

    fig = Figure(figsize=(6.4, 4.0))
    ax = fig.subplots()
    for j, (label, points) in enumerate(series.items()):
        xs, ys, sds = [], [], []
        for size in sorted(points):
            values = _values(runs.get(points[size], []))
            if values:
                xs.append(size)
                ys.append(statistics.fmean(values))
                sds.append(statistics.stdev(values) if len(values) > 1 else 0.0)
        if xs:
            ax.errorbar(xs, ys, yerr=sds, marker="o", capsize=3, color=f"C{j}", label=label)
    for value, label, style in ((floor, "floor", ":"), (ceiling, "BC ceiling", "--")):
        if value is not None:
            ax.axhline(value, color="black", linestyle=style, linewidth=1, label=f"{label} ({value:.2f} cm)")
    if baseline is not None:
        ax.axhline(baseline[1], color="grey", linestyle="-.", linewidth=1, label=f"{baseline[0]} ({baseline[1]:.2f} cm)")
    ax.set_xscale("log")
    sizes = sorted({size for points in series.values() for size in points})
    ax.set_xticks(sizes, [f"{size:,}" for size in sizes])
    ax.minorticks_off()
    ax.set_xlabel("site demonstrations (log scale)")
    ax.set_ylabel("planner APE (cm), mean ± sd over seeds")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110, metadata={"Software": SOFTWARE})
