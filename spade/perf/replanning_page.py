"""The replanning page (``docs/results/replanning.md``): what the decoder's prior toward the previous plan
(``replan_prior``, :class:`spade.metrics.decoding.PathDecoder`) buys in closed loop, written from the drive records of
``python -m spade.perf.replanning`` (``docs/results/records/replanning/``).

The same students are driven with the prior off and on, so each setting is compared with the prior off by a paired
t-test over the students (Holm's correction over the page's tests). The page leads with its verdict, beside the
followed demonstration (the follower's own cost) and the targets the deployment asks of a planner.

Usage: ``python -m spade.perf.replanning_page RECORDS_DIR OUT.md``.
"""

from __future__ import annotations

import json
import math
import statistics
import sys
from pathlib import Path
from typing import Any

from spade.experiments.reporting.stats import holm, mean_sd, paired, significance
from spade.utils.markdown import markdown_table
from spade.utils.provenance import provenance_lines

__all__ = ["TARGETS", "load_drive_records", "replanning_page"]

FIGURES: tuple[tuple[str, str, bool], ...] = (
    ("ape_cm", "closed-loop APE (cm)", False),
    ("mode_switches", "mode switches / scenario", False),
    ("commit_rate", "commits", True),
    ("success_rate", "success", True),
)
"""(closed_loop/<key>, header, shown as a percent) of the page's table."""
TARGETS: dict[str, dict[str, tuple[str, float]]] = {
    "clean": {"ape_cm": ("<=", 7.0), "mode_switches": ("<=", 0.25), "commit_rate": (">=", 0.70),
              "success_rate": (">=", 1.0)},
    "perturbed": {"ape_cm": ("<=", 20.0), "success_rate": (">=", 0.99)},
}
"""What a robot operator asks of a replanning student (the deployment's targets, set before any measurement)."""
TESTED = ("ape_cm", "mode_switches")


def load_drive_records(records_dir: str | Path) -> list[dict[str, Any]]:
    """Every drive record (one student, condition and prior) of ``records_dir``."""
    return [json.loads(p.read_text()) for p in sorted(Path(records_dir).glob("*.json")) if p.name != "summary.json"]


def _fmt(value: float, percent: bool) -> str:
    return f"{100 * value:.0f} %" if percent else f"{value:.2f}"


def _cell(values: list[float], percent: bool) -> str:
    return mean_sd(values, lambda v: _fmt(v, percent))


def _paired_by_student(a: dict[str, float], b: dict[str, float]) -> float | None:
    """Two-sided paired t-test p of ``a`` against ``b`` over the students both hold (None below two or no spread)."""
    keys = sorted(set(a) & set(b))
    return paired([a[k] for k in keys], [b[k] for k in keys])


ALWAYS = 100.0
"""A ``replan_keep`` this large keeps the previous plan whenever it is usable (a fresh path would have to cost a
hundredth of it): the diagnostic bound of what holding one plan could buy."""
DATA = "site_L"
"""The drives' test set the targets are set on (the science test's held-out maps); another one (the unseen real maps,
``realmap_L``) is its own condition, whose direction the page shows without targets."""
Setting = tuple[float, float]
"""(replan_prior, replan_keep) of a drive, keep -1 for off (so that settings sort)."""
OFF: Setting = (0.0, -1.0)


def setting_label(setting: Setting) -> str:
    """``off``, ``prior 0.9``, ``keep 0.5`` or ``prior 0.9 + keep 0.5``."""
    prior, keep = setting
    kept = [] if keep < 0 else [f"keep {keep:g}" if keep < ALWAYS else "keep while usable"]
    return " + ".join(([f"prior {prior:g}"] if prior > 0 else []) + kept) or "off"


def replanning_page(records: list[dict[str, Any]], command: str = "") -> str:
    """The page's markdown from the drive records."""
    groups: dict[tuple[str, Setting], dict[str, dict[str, float]]] = {}
    followed: dict[str, list[dict[str, float]]] = {}
    for r in records:
        metrics = r["metrics"]
        keep = r.get("replan_keep")
        condition = r["condition"] if r.get("data") in (None, DATA) else f"{r['condition']}, {r['data']}"
        setting = (float(r["replan_prior"]), -1.0 if keep is None else float(keep))
        per_student = groups.setdefault((condition, setting), {})
        per_student[r["run"]] = {k: metrics[f"closed_loop/{k}"] for k, _, _ in FIGURES
                                 if f"closed_loop/{k}" in metrics}
        if "closed_loop/followed/ape_cm" in metrics:
            followed.setdefault(condition, []).append(
                {k: metrics.get(f"closed_loop/followed/{k}") for k, _, _ in FIGURES})
    conditions = sorted({c for c, _ in groups}, key=lambda c: (c != "clean", c))
    tests: list[tuple[str, Setting, str, float | None]] = []
    for (condition, setting), students in sorted(groups.items()):
        off = groups.get((condition, OFF))
        if setting == OFF or off is None:
            continue
        for key in TESTED:
            tests.append((condition, setting, key,
                          _paired_by_student({s: v[key] for s, v in students.items() if key in v},
                                             {s: v[key] for s, v in off.items() if key in v})))
    adjusted = dict(zip([(c, p, k) for c, p, k, _ in tests], holm([p for *_, p in tests])))

    def mean(condition: str, setting: Setting, key: str) -> float | None:
        values = [v[key] for v in groups.get((condition, setting), {}).values() if key in v]
        return statistics.fmean(values) if values else None

    verdict = []
    for condition in conditions:
        settings = sorted(s for c, s in groups if c == condition and s != OFF)
        if not settings or (condition, OFF) not in groups:
            continue
        best = min(settings, key=lambda s: mean(condition, s, "ape_cm") or math.inf)
        parts = []
        for key in TESTED:
            label = next(h for k, h, _ in FIGURES if k == key)
            p = adjusted.get((condition, best, key))
            told = "no test" if p is None else f"Holm p {p:.2g}, {significance(p)}"
            parts.append(f"{label} {mean(condition, OFF, key):.2f} → {mean(condition, best, key):.2f} ({told})")
        targets = TARGETS.get(condition, {})
        missed = [next(h for k, h, _ in FIGURES if k == key) for key, (op, goal) in targets.items()
                  if (value := mean(condition, best, key)) is not None
                  and not (value <= goal + 1e-9 if op == "<=" else value >= goal - 1e-9)]
        verdict.append(f"- **{condition}**, the best setting ({setting_label(best)}) against off: " + "; ".join(parts)
                       + ". "
                       + (f"Targets missed: {', '.join(missed)}." if missed else "Every target met." if targets
                          else "No targets on this test set: its direction only."))
        held = [s for s in settings if s[1] >= ALWAYS]
        follow = followed.get(condition, [{}])[0]
        if held and follow.get("ape_cm") is not None:
            h = min(held, key=lambda s: mean(condition, s, "ape_cm") or math.inf)
            ape, switches = mean(condition, h, "ape_cm"), mean(condition, h, "mode_switches")
            if (ape is not None and switches is not None and switches <= (follow.get("mode_switches") or 0) + 0.1
                    and ape > 1.5 * follow["ape_cm"]):
                verdict.append(f"- **What bounds it** ({condition}): holding one plan wherever the map allows "
                               f"({setting_label(h)}) drives at {ape:.2f} cm with {switches:.2f} mode switches per "
                               f"scenario, against {follow['ape_cm']:.2f} cm for the demonstration followed: the "
                               "error left is the plans' own, not their wavering.")
    students = max((len(v) for v in groups.values()), default=0)
    provenance = provenance_lines(None)
    provenance[0] += f"; drives at {sorted({str(r.get('commit'))[:7] for r in records})}"
    body = []
    for condition in conditions:
        for (c, setting), group in sorted(groups.items()):
            if c == condition:
                body.append([condition, setting_label(setting),
                             *(_cell([v[k] for v in group.values() if k in v], pct) for k, _, pct in FIGURES)])
        if followed.get(condition):
            body.append([condition, "the demonstration, followed",
                         *(_cell([f[k] for f in followed[condition] if f.get(k) is not None][:1], pct)
                           for k, _, pct in FIGURES)])
    lines = ["# Replanning that keeps its turn: the decoder's prior and keeping the previous plan", "",
             "Two levers change what a replanning student drives: the decoder's prior toward the previous plan "
             "(`replan_prior`: its `-log p` discounted near it, then decoded afresh) and keeping the previous plan "
             "itself unless a fresh path is clearly cheaper (`replan_keep`: hysteresis on the whole plan; \"keep while usable\" "
             "holds the first plan wherever the map allows it, the bound of what holding one plan could buy). "
             f"Each setting is compared with both off on the "
             f"same {students} students by a paired t-test (Holm's correction over the page's "
             f"{sum(p is not None for *_, p in tests)} tests). The deciding figures in closed loop are success, then "
             "closed-loop APE (the [metrics reference](../reference/metrics.md) says why); mode switches and "
             "commitment say whether the plan holds its turn.", "", *verdict, "",
             *markdown_table(["condition", "setting", *(h for _, h, _ in FIGURES)], body)]
    lines += ["", "Targets: " + "; ".join(f"{c}: " + ", ".join(f"{next(h for k, h, _ in FIGURES if k == key)} {op} "
                                                                  f"{_fmt(goal, key.endswith('rate'))}"
                                                                  for key, (op, goal) in t.items())
                                      for c, t in TARGETS.items()) + ".", "",
              "## Provenance", "",
              f"- drives: `{records[0].get('command', '').split(' --ckpt')[0] if records else ''} --ckpt ... "
              f"--weights ... --keep ...` ({len(records)} records in docs/results/records/replanning/, "
              "scenarios per test set: " + ", ".join(f"{d or DATA} {n}" for d, n in sorted(
                  {(r.get("data"), r.get("scenarios")) for r in records}, key=str)) + ")",
              f"- page: `{command or 'python -m spade.perf.replanning_page'}`",
              *provenance,
              f"- drive wall time: {sum(float(r.get('seconds') or 0) for r in records) / 60:.0f} min in all", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    args = list(sys.argv[1:] if argv is None else argv)
    if len(args) != 2:
        raise SystemExit("usage: python -m spade.perf.replanning_page RECORDS_DIR OUT.md")
    records = load_drive_records(args[0])
    if not records:
        raise SystemExit(f"error: no drive records in {args[0]}; make them with python -m spade.perf.replanning")
    Path(args[1]).write_text(replanning_page(records, "python -m spade.perf.replanning_page " + " ".join(args)))
    print(f"wrote {args[1]}")


if __name__ == "__main__":
    main()
