"""The one catalog of SPADE's figures: each metric's name, label, unit, direction, number format and meaning.

A figure's *name* is its logged key without the stage (``test/``, ``val/``, ``untrained/``): ``ape_cm``,
``planner/over_20cm_rate``, ``closed_loop/success_rate``. Families are read by prefix, so each figure is written
once here however many predictors and readings log it:

- ``planner/<figure>``: the same figure of the path the planner decodes by search (labels ``planner ...``);
- ``mean_map/planner/<figure>``: an expert's planner on the mean of its K samples' maps (``mean-map planner ...``);
- ``closed_loop/<figure>`` (and ``closed_loop/<reference>/<figure>``): the figure of a scenario driven from start to
  goal (``closed-loop ...``; the closed-loop-only figures, such as ``closed_loop/success_rate``, are entries);
- ``baseline/<name>/<figure>``: a classical baseline's figure on the same test set (the figure's own label);
- ``ceiling/<figure>``, ``demo_target/<figure>``, ``oracle_sample/<figure>``, ``oracle_medoid/<figure>``: the
  references every test logs beside its predictors (:mod:`spade.metrics.plausible`): the BC ceiling, the decoder's
  floor on the demonstration's own target, and the oracle as a planner (one draw; the medoid of its draws);
- ``medoid/planner/<figure>``: an expert's planner reading of the medoid of its K samples' decoded paths.

Tables, reports, run descriptions, closing summaries and ``gpu_check`` read labels, formats and the ordered figure
lists at the bottom from here; :func:`label`, :func:`fmt`, :func:`lower_is_better` and :func:`figure` take any
name (prefixed, staged or not). Importing this module imports nothing of SPADE.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

__all__ = [
    "BASELINE_LABELS",
    "BASELINE_ROW_LABELS",
    "CELL",
    "CLOSED_LOOP",
    "DESCRIPTION",
    "Figure",
    "GPU_CHECK",
    "HEADLINE",
    "PREFERENCE",
    "RUNS_VIEW",
    "SUMMARY",
    "TABLE",
    "TEACHER",
    "figure",
    "fmt",
    "format_params",
    "glossary",
    "header",
    "known",
    "label",
    "lower_is_better",
    "mlflow_key",
]

BASELINE_LABELS: dict[str, str] = {"straight": "straight line", "shortest": "Nav2-like shortest path",
                                   "heading": "heading template"}
"""How verdicts and the closed-loop page name the classical predictors (:data:`spade.metrics.baselines.BASELINES`)
in a sentence."""
BASELINE_ROW_LABELS: dict[str, str] = {**BASELINE_LABELS, "shortest": "shortest path (Nav2-like)"}
"""How a table names them as reference rows (every table shows them, on the same test sets: a learned row that does
not beat them has learned nothing worth deploying)."""

STAGES = ("test/", "val/", "untrained/")
"""The prefixes a run logs its figures under (a figure's name is what follows)."""


def format_params(value: float) -> str:
    """117025 -> '117k', 1926209 -> '1.93M', 31114785 -> '31.1M' (three significant figures)."""
    for scale, suffix in ((1e9, "G"), (1e6, "M"), (1e3, "k")):
        if abs(value) >= scale:
            return f"{value / scale:.3g}{suffix}"
    return f"{value:.0f}"


def _missing(value: float | None) -> bool:
    return value is None or (isinstance(value, float) and math.isnan(value))


@dataclass(frozen=True)
class Figure:
    """One metric: how it is named, labelled, formatted and read.

    ``unit``: ``cm``, ``share`` (a fraction, shown in per cent), ``count``, ``ratio``, ``px``, ``ms``, ``s``,
    ``deg/m``, ``params`` or ``""``; ``direction``: ``lower`` or ``higher`` is better, ``""`` when neither (a
    count of instances, a time that is not the figure judged). ``label`` heads a table's column (the unit in
    brackets where the cells do not show it); ``header`` is the compact column header of a run's description.
    ``staged``: logged under a stage (``test/<name>``); ``model/params`` and ``margin/active`` are not.
    """

    name: str
    label: str
    unit: str
    direction: str
    format_spec: str
    meaning: str
    header: str = ""
    staged: bool = True
    key: str = ""  # a report's key (CSV column): the name with "/" as "_" unless given

    def __post_init__(self) -> None:
        if self.direction not in ("lower", "higher", ""):
            raise ValueError(f"{self.name}: direction must be lower, higher or '', got {self.direction!r}")
        if not self.key:
            object.__setattr__(self, "key", self.name.replace("/", "_"))
        if not self.header:
            object.__setattr__(self, "header", self.label)

    @property
    def mlflow_key(self) -> str:
        """The key a test logs it under (``test/planner/ape_cm``; ``model/params`` as it is)."""
        return f"test/{self.name}" if self.staged else self.name

    @property
    def fmt(self) -> str:
        """The number format of a table's cell (``.2f``, ``.1%``, ``params``)."""
        return self.format_spec

    @property
    def lower_is_better(self) -> bool | None:
        return {"lower": True, "higher": False}.get(self.direction)

    def format(self, value: float | None) -> str:
        """A table's cell: ``n/a`` for a missing value."""
        if _missing(value):
            return "n/a"
        if self.format_spec == "params":
            return format_params(value)
        return format(value, self.format_spec)

    def format_compact(self, value: float | None) -> str:
        """A run description's cell: centimetres to a tenth, shares in whole per cent (the header says %)."""
        if _missing(value):
            return "n/a"
        if self.unit == "cm":
            return f"{value:.1f}"
        if self.unit == "share":
            return f"{100 * value:.0f}"
        return self.format(value)


def _f(name: str, label: str, unit: str, direction: str, format_spec: str, meaning: str, header: str = "",
       **extra: object) -> Figure:
    return Figure(name, label, unit, direction, format_spec, meaning, header, **extra)  # type: ignore[arg-type]


_ENTRIES: tuple[Figure, ...] = (
    # the paper's figures of a predicted image (its path extracted by threshold and skeleton), spade.metrics.ape
    _f("fid", "FID", "", "lower", ".2f", "Frechet distance between shape features of the predicted and the "
       "demonstrated paths (more alike in shape: lower)"),
    _f("ape_cm", "APE (cm)", "cm", "lower", ".2f", "mean distance between the extracted path and the demonstration "
       "(an instance with no path is a failure, not averaged)", "APE cm"),
    _f("ape_std_cm", "APE sd (cm)", "cm", "", ".2f", "standard deviation of the APE over the extracted instances"),
    _f("ape_median_cm", "median APE (cm)", "cm", "lower", ".2f", "median APE over the extracted instances"),
    _f("ape_max_cm", "max APE (cm)", "cm", "lower", ".2f", "largest APE of an extracted instance"),
    _f("score_cm", "APE, failures as straight line (cm)", "cm", "lower", ".2f", "APE with a failure scored as "
       "the straight line from start to goal (what model selection compares)"),
    _f("failures", "failed instances", "count", "lower", ".0f", "instances from which no path could be extracted"),
    _f("failure_rate", "failures", "share", "lower", ".1%", "share of instances from which no path could be "
       "extracted", "fail %"),
    _f("over_20cm_rate", ">20 cm", "share", "lower", ".1%", "share of instances whose APE exceeds 20 cm "
       "(failures included): the tail a mean hides", ">20cm %"),
    _f("instances", "instances", "count", "", ".0f", "test instances scored"),
    _f("scenarios", "test scenarios", "count", "", ".0f", "distinct test scenarios scored: the unit of a results "
       "page's intervals (a scenario's states are near-duplicates)"),
    # spade.metrics.hausdorff
    _f("hd19", "Hd19", "count", "lower", ".0f", "instances whose Hausdorff distance to the demonstration exceeds "
       "0.95 m (the paper's 19 px): stray artifacts", "Hd19 n"),
    _f("hd19_rate", "Hd19 share", "share", "lower", ".1%", "share of instances counted by Hd19"),
    _f("hausdorff_mean_px", "Hausdorff mean (px)", "px", "lower", ".1f", "mean Hausdorff distance of the "
       "non-empty predictions"),
    _f("hausdorff_median_px", "Hausdorff median (px)", "px", "lower", ".1f", "median Hausdorff distance of the "
       "non-empty predictions"),
    _f("empty", "empty predictions", "count", "lower", ".0f", "instances whose thresholded prediction is empty"),
    # FID's companions (spade.metrics.fid)
    _f("fid_real_count", "FID real images", "count", "", ".0f", "demonstrated paths FID saw"),
    _f("fid_fake_count", "FID predicted images", "count", "", ".0f", "predicted paths FID saw"),
    # the planner's own figures (spade.metrics.path_metrics)
    _f("low_confidence_rate", "low confidence", "share", "lower", ".1%", "share of instances whose decoded path "
       "runs more than a tenth of its length through pixels with p < 0.5"),
    _f("low_share_mean", "low-probability share", "share", "lower", ".1%", "mean share of a decoded path's "
       "length through pixels with p < 0.5"),
    # the figures that see a preference (spade.metrics.preference), where the test set has alternatives
    _f("floor_cm", "floor (cm)", "cm", "lower", ".2f", "APE of the best single path under the test set's "
       "alternative demonstrations: no predictor can score much below it"),
    _f("ape_over_floor", "APE / floor", "ratio", "lower", ".2f", "mean APE over the mean floor on the same "
       "instances (1 is the floor)"),
    _f("plausibility_cm", "plausibility (cm)", "cm", "lower", ".2f", "distance to the nearest of the "
       "demonstration and its alternatives (a path an operator could have drawn: 0)", "plaus. cm"),
    _f("commit_rate", "commits", "share", "higher", ".0%", "share of instances whose path follows one of the "
       "demonstration and its alternatives, not a blend", "commit %"),
    _f("pref_instances", "instances with alternatives", "count", "", ".0f", "instances the preference figures "
       "scored"),
    # an expert's test (spade.metrics.preference.SpreadMetrics, ExpertModule.test_step)
    _f("spread_cm", "spread (cm)", "cm", "", ".2f", "distance between two samples' decoded paths of one state"),
    _f("spread_ratio", "spread / generator's", "ratio", "", ".2f", "the samples' spread over the generator's "
       "(1: as varied as the operator's choices)"),
    _f("generator_spread_cm", "generator spread (cm)", "cm", "", ".2f", "distance between two of the generator's "
       "paths of one state"),
    _f("seconds_per_sample", "s / sample", "s", "lower", ".4g", "sampling or prediction time per instance"),
    # a model and its training
    _f("model/params", "params", "params", "", "params", "trainable parameters", staged=False, key="params"),
    _f("margin/active", "margin active in the last epoch", "share", "", ".0%", "a guided row's share of active "
       "margins in its last training epoch", staged=False),
    # closed loop only (spade.metrics.closed_loop): a scenario driven from start to goal
    _f("closed_loop/success_rate", "success", "share", "higher", ".0%", "share of scenarios that reached the goal"),
    _f("closed_loop/collision_rate", "collision", "share", "lower", ".0%", "share of scenarios ended on a lethal "
       "cell"),
    _f("closed_loop/timeout_rate", "timeout", "share", "lower", ".0%", "share of scenarios out of time"),
    _f("closed_loop/no_plan_rate", "no plan", "share", "lower", ".0%", "share of scenarios ended with no plan to "
       "follow"),
    _f("closed_loop/length_ratio", "length ratio", "ratio", "", ".2f", "executed length over the "
       "demonstration's (successful scenarios)"),
    _f("closed_loop/smoothness_deg_per_m", "smoothness (deg/m)", "deg/m", "lower", ".1f", "mean absolute "
       "heading change per metre of the executed path"),
    _f("closed_loop/replan_change_cm", "replan change (cm)", "cm", "lower", ".2f", "how far a replan moved the "
       "path still ahead"),
    _f("closed_loop/mode_switches", "mode switches", "count", "lower", ".2f", "changes of the plan's turn side or "
       "radius band between replans, per scenario"),
    _f("closed_loop/plan_ms", "plan (ms)", "ms", "", ".1f", "wall time per planning query"),
    _f("closed_loop/replans", "plans", "count", "", ".1f", "planning queries per scenario"),
    _f("closed_loop/episodes", "scenarios", "count", "", ".0f", "scenarios driven"),
    _f("closed_loop/seconds", "driving (s)", "s", "", ".0f", "wall time of the drives"),
)

_BY_NAME: dict[str, Figure] = {f.name: f for f in _ENTRIES}
_BY_KEY: dict[str, Figure] = {f.key: f for f in _ENTRIES if f.key != f.name.replace("/", "_")}  # "params"
if len(_BY_NAME) != len(_ENTRIES):  # pragma: no cover - a duplicate entry is a bug of this module
    raise RuntimeError("spade.metrics.catalog: a figure is listed twice")

# family prefix -> (label qualifier, header qualifier); longest first
_FAMILIES: tuple[tuple[str, str, str], ...] = (
    ("mean_map/planner/", "mean-map planner", "mean-map plan"),
    ("medoid/planner/", "medoid planner", "medoid plan"),
    ("planner/", "planner", "plan"),
    ("closed_loop/", "closed-loop", "closed-loop"),
)
# a family member whose compact header is not the qualified one (a run description's columns)
_FAMILY_HEADERS = {"planner/plausibility_cm": "plaus. cm", "planner/commit_rate": "commit %"}
# readings that stand for a predictor: their figures are the figure's own (the predictor is named elsewhere)
_PREDICTOR_PREFIXES = ("baseline/", "followed/", "demonstration/", "ceiling/", "demo_target/", "oracle_sample/",
                       "oracle_medoid/")


def _unstaged(name: str) -> str:
    for stage in STAGES:
        if name.startswith(stage):
            return name[len(stage):]
    return name


def _drop_predictor(name: str) -> str:
    """``baseline/straight/planner/ape_cm`` -> ``planner/ape_cm``; ``followed/ape_cm`` -> ``ape_cm``."""
    if name.startswith("baseline/"):
        parts = name.split("/", 2)
        return parts[2] if len(parts) == 3 else name
    for prefix in _PREDICTOR_PREFIXES[1:]:
        if name.startswith(prefix):
            return name[len(prefix):]
    return name


def _lookup(name: str) -> Figure | None:
    name = _drop_predictor(_unstaged(name))
    if name in _BY_NAME:
        return _BY_NAME[name]
    if name in _BY_KEY:
        return _BY_KEY[name]
    for prefix, qualifier, short in _FAMILIES:
        if not name.startswith(prefix):
            continue
        rest = name[len(prefix):]
        if prefix == "closed_loop/":  # closed_loop/baseline/shortest/ape_cm: the closed-loop figure ape_cm
            whole = prefix + _drop_predictor(rest)
            if whole in _BY_NAME:
                return replace(_BY_NAME[whole], name=name, key=name.replace("/", "_"))
            rest = _drop_predictor(rest)
        base = _BY_NAME.get(rest)
        if base is None:
            return None
        return replace(base, name=name, key=name.replace("/", "_"), label=f"{qualifier} {base.label}",
                       header=_FAMILY_HEADERS.get(name, f"{short} {base.header}"),
                       meaning=f"{base.meaning} ({qualifier})")
    return None


def known(name: str) -> bool:
    """Whether ``name`` (staged, prefixed or not) is a catalogued figure."""
    return _lookup(name) is not None


def figure(name: str) -> Figure:
    """The catalogued :class:`Figure` of ``name``: ``ape_cm``, ``test/planner/ape_cm``, ``mean_map/planner/hd19``,
    ``closed_loop/baseline/shortest/ape_cm``, ``test/baseline/straight/over_20cm_rate``, ``model/params``."""
    found = _lookup(name)
    if found is None:
        raise KeyError(f"{name!r} is not in the metric catalog (spade.metrics.catalog); add it there")
    return found


def label(name: str, qualified: bool = True) -> str:
    """A table column's label: ``APE (cm)``; ``planner APE (cm)`` for ``planner/ape_cm`` (``qualified=False``:
    without the family's qualifier, for a table whose columns are all of one family, e.g. ``closed_loop/``)."""
    if qualified:
        return figure(name).label
    bare = _drop_predictor(_unstaged(name))
    for prefix, _, _ in _FAMILIES:
        if bare.startswith(prefix) and bare not in _BY_NAME:
            return figure(bare[len(prefix):]).label
    return figure(bare).label


def header(name: str) -> str:
    """The compact column header of a run's description: ``APE cm``, ``fail %``, ``plan APE cm``."""
    return figure(name).header


def fmt(name: str, value: float | None, compact: bool = False) -> str:
    """``value`` as a table shows ``name`` (``compact``: as a run's description does); ``n/a`` when missing."""
    f = figure(name)
    return f.format_compact(value) if compact else f.format(value)


def lower_is_better(name: str) -> bool | None:
    """True when a lower value is better, False when a higher one is, None when neither is judged."""
    return figure(name).lower_is_better


def mlflow_key(name: str, stage: str = "test") -> str:
    """The key ``name`` is logged under at ``stage``: ``test/planner/ape_cm``; ``model/params`` as it is."""
    return f"{stage}/{name}" if figure(name).staged else name


def meaning(names: tuple[str, ...]) -> str:
    """One sentence per figure of ``names``: ``<header>: <meaning>`` (a legend under a table)."""
    return "; ".join(f"{header(n)}: {figure(n).meaning}" for n in names) + "."


# what a family's qualifier means, for a glossary that gives each figure's meaning once
_FAMILY_MEANINGS = {
    "planner/": "read on the path the planner decodes by search (the path a robot drives)",
    "mean_map/planner/": "read on the planner's path through the mean of an expert's K samples' maps",
    "medoid/planner/": "read on the medoid of an expert's K samples' decoded paths",
    "closed_loop/": "read on a scenario driven from start to goal",
}


def _family(name: str) -> tuple[str, str] | None:
    """(family prefix, base figure) of a family member (``planner/ape_cm`` -> ``("planner/", "ape_cm")``)."""
    bare = _drop_predictor(_unstaged(name))
    if bare in _BY_NAME:
        return None
    for prefix, _, _ in _FAMILIES:
        if bare.startswith(prefix) and bare[len(prefix):] in _BY_NAME:
            return prefix, bare[len(prefix):]
    return None


def glossary(names: tuple[str, ...]) -> str:
    """A legend under a table of ``names`` that gives each meaning once: the figures that share one (``APE cm`` and
    the planner's ``plan APE cm``) under one entry, then one entry per family saying what its qualifier means."""
    entries: dict[str, list[str]] = {}  # meaning -> headers, in the order of ``names``
    families: dict[str, list[str]] = {}  # family prefix -> its members' headers
    for name in names:
        member = _family(name)
        base = figure(member[1]) if member else figure(name)
        entries.setdefault(base.meaning, [])
        if header(name) not in entries[base.meaning]:
            entries[base.meaning].append(header(name))
        if member:
            families.setdefault(member[0], []).append(header(name))
    parts = [f"{' / '.join(headers)}: {text}" for text, headers in entries.items()]
    parts += [f"{', '.join(headers)}: {_FAMILY_MEANINGS[prefix]}" for prefix, headers in families.items()]
    return "; ".join(parts) + "."


# -- the ordered figure lists that the pages and summaries show --------------------------------------------------
CELL: tuple[str, ...] = ("fid", "ape_cm", "hd19", "failure_rate", "over_20cm_rate", "planner/ape_cm",
                         "planner/over_20cm_rate")
"""A table's cell: the paper's FID / APE / Hd19 (APE and Hd19 of the paper's skeleton extraction; FID of the decoded
path drawn like the ground truth), the failures, the tail (share of instances over 20 cm), and the planner's APE and
tail (the search-decoded path a robot would drive, spade.metrics.decoding)."""

PREFERENCE: tuple[str, ...] = ("floor_cm", "planner/ape_over_floor", "planner/plausibility_cm",
                               "planner/commit_rate")
"""The preference figures a table shows beside its cells (spade.metrics.preference), where its runs logged them."""

TABLE: tuple[str, ...] = (*CELL, "planner/low_confidence_rate", *PREFERENCE, "model/params", "margin/active")
"""Every figure a table's report reads from a row's runs (its CSV columns, in this order)."""

DESCRIPTION: tuple[str, ...] = ("planner/ape_cm", "planner/over_20cm_rate", "planner/plausibility_cm",
                                "planner/commit_rate", "ape_cm", "over_20cm_rate", "failure_rate", "fid", "hd19")
"""The test figures a run's description shows (its figures table), in this order: the figure that decides first,
with its tail (:mod:`spade.metrics.verdict`), then plausibility and commitment, then the paper's."""

RUNS_VIEW: tuple[str, ...] = (*DESCRIPTION, "model/params")
"""The figures SPADE's MLflow runs view shows as its first columns, in this order (rounded: run tags that
:mod:`spade.tracking.figure_tags` writes beside the full-precision metrics)."""

SUMMARY: tuple[str, ...] = ("planner/ape_cm", "planner/over_20cm_rate", "planner/ape_over_floor",
                            "planner/plausibility_cm", "planner/commit_rate", "planner/low_confidence_rate", "ape_cm",
                            "over_20cm_rate", "failure_rate", "fid", "hd19", "seconds_per_sample")
"""The figures a run's closing summary prints per predictor (the floor once, on its own line): the figure that
decides first, with its tail (:mod:`spade.metrics.verdict`), then the planner's others, then the paper's."""

HEADLINE: tuple[str, ...] = ("ape_cm", "over_20cm_rate", "failure_rate", "planner/ape_cm")
"""The few figures a one-line report of a test prints (a test of a checkpoint elsewhere)."""

TEACHER: tuple[str, ...] = ("planner/ape_cm", "planner/over_20cm_rate", "planner/failure_rate",
                            "planner/ape_over_floor", "planner/plausibility_cm", "planner/commit_rate")
"""The teacher page's columns: the planner's figures of every expert and student."""

CLOSED_LOOP: tuple[str, ...] = ("closed_loop/success_rate", "closed_loop/collision_rate", "closed_loop/timeout_rate",
                                "closed_loop/ape_cm", "closed_loop/plausibility_cm", "closed_loop/commit_rate",
                                "closed_loop/mode_switches", "closed_loop/replan_change_cm",
                                "closed_loop/smoothness_deg_per_m", "closed_loop/plan_ms")
"""The closed-loop page's columns (a drive's figures)."""

GPU_CHECK: tuple[str, ...] = ("ape_cm", "planner/ape_cm", "hd19", "failure_rate", "over_20cm_rate", "fid")
"""The test figures ``gpu_check``'s pipeline reads back from each run and reports."""
