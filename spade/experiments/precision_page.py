"""The bf16 science check (``python -m spade.report table=precision``): does bf16 autocast change what a run learns?

Each bf16 row (``conf/experiment/site_*_bf16_L.yaml``: ``trainer.precision=bf16-mixed``, fp32 weights, optimiser and
losses) is tested against its fp32 twin on the oracle page's science test set, figure by figure: the deciding
planner APE, the floor ratio, plausibility and commitment, by Welch's test over seeds with Holm's correction over
every test of the page; the page also states ``trainer=cpu``'s precision as the config sets it. It reads the oracle page's run records (the rows share its MLflow experiment), so it regenerates without
the store.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from omegaconf import OmegaConf

from spade.experiments.reporting.stats import ALPHA, holm, mean_sd, welch
from spade.experiments.run_records import RunRecord, export_records, load_records, store_exists
from spade.paths import CONF_DIR
from spade.utils.markdown import markdown_table
from spade.utils.provenance import command_line, provenance_lines, shown_path

__all__ = ["precision_report", "FIGURES"]

FIGURES: tuple[tuple[str, str, str], ...] = (
    ("test/planner/ape_cm", "planner APE", "cm"),
    ("test/planner/ape_over_floor", "floor ratio", "x"),
    ("test/planner/plausibility_cm", "plausibility", "cm"),
    ("test/planner/commit_rate", "commits", "%"),
)
"""(metric, label, unit) of the figures compared; the first decides (docs/reference/metrics.md)."""


def _values(runs: list[RunRecord], metric: str) -> list[float]:
    return [float(r.metrics[metric]) for r in runs if metric in r.metrics]


def _shown(values: list[float], unit: str) -> str:
    if not values:
        return "-"
    scale, fmt = (100.0, ".0f") if unit == "%" else (1.0, ".2f")
    text = mean_sd([v * scale for v in values], fmt)
    return f"{text} %" if unit == "%" else text


def precision_report(tracking_uri: str, output_dir: str | Path | None, settings: Mapping[str, Any]) -> tuple[str, dict]:
    """Export the rows' runs into the records (when the store has them), then write ``<page>.md`` from the records."""
    pairs: dict[str, str] = dict(settings.get("pairs") or {})
    labels: dict[str, str] = dict(settings.get("labels") or {})
    if not pairs:
        raise ValueError("precision.pairs is empty: map each bf16 row to its fp32 twin, e.g. "
                         "{site_bc_bf16_L: site_bc_L}")
    records_dir = Path(str(settings["records_dir"]))
    names = sorted({*pairs, *pairs.values()})
    if store_exists(tracking_uri):
        export_records(tracking_uri, str(settings.get("experiment", "oracle")), records_dir, names)
    runs = load_records(records_dir)[0] if records_dir.is_dir() else []
    by_name: dict[str, list[RunRecord]] = {}
    for run in runs:
        if run.row in names:
            by_name.setdefault(run.row, []).append(run)

    tests: list[dict[str, Any]] = []
    for low, full in pairs.items():
        for metric, label, unit in FIGURES:
            a, b = _values(by_name.get(low, []), metric), _values(by_name.get(full, []), metric)
            p, _ = welch(a, b)
            tests.append({"pair": low, "metric": metric, "label": label, "unit": unit, "a": a, "b": b, "p": p})
    for test, adjusted in zip(tests, holm([t["p"] for t in tests])):
        test["holm"] = adjusted
    told_apart = [t for t in tests if t["holm"] is not None and t["holm"] < ALPHA]
    untested = [low for low, full in pairs.items() if len(by_name.get(low, [])) < 2 or len(by_name.get(full, [])) < 2]

    title = str(settings.get("title", "bf16 autocast: the same science?"))
    verdict = []
    if untested:
        verdict.append(f"- Not yet tested (fewer than 2 seeds on a side): {', '.join(labels.get(n, n) for n in untested)}.")
    tested = [low for low in pairs if low not in untested]
    if tested:
        if told_apart:
            moved = "; ".join(f"{labels.get(t['pair'], t['pair'])}: {t['label']} (Holm p {t['holm']:.3g})"
                              for t in told_apart)
            verdict.append(f"- **bf16 changes the science**: told apart from fp32 on {moved}.")
        else:
            verdict.append(f"- **bf16 is within noise of fp32** on {', '.join(labels.get(n, n) for n in tested)}: "
                           "no figure below is told apart (Welch over seeds, Holm over the page). Not told apart is "
                           "not shown equal: the sd columns say how large a change the seeds could hide.")
    default = str(OmegaConf.load(CONF_DIR / "trainer" / "cpu.yaml").get("precision"))
    verdict.append(f"- `trainer=cpu`'s precision is `{default}`" + (
        ": bf16-mixed where the CPU (AVX-512 BF16 or AMX) or the GPU has native bf16, 32-true elsewhere."
        if default == "auto" else "; bf16 is opt-in (`trainer.precision=bf16-mixed`)."))
    if tested:
        verdict.append("- What bf16 buys in time is the [speed page](speed.md)'s lever table (each lever against "
                       "the same run's baseline, interleaved): the rows' own wall times come from different "
                       "machines and loads, so they are not compared here.")

    body = []
    for test in tests:
        low = test["pair"]
        body.append([labels.get(low, low), test["label"],
                     f"{_shown(test['a'], test['unit'])} ({len(test['a'])})",
                     f"{_shown(test['b'], test['unit'])} ({len(test['b'])})",
                     "-" if test["p"] is None else f"{test['p']:.2g} / {test['holm']:.2g}",
                     "no test" if test["holm"] is None else "told apart" if test in told_apart else "not told apart"])
    lines = [f"# {title}", "", "## Verdict", "", *verdict, "",
             "## Figures, bf16 against fp32", "",
             "The oracle page's science test set (held-out maps); mean ± sd over seeds (their number in brackets); "
             "Welch's p, then Holm's over the page. The deciding figure is the planner's APE "
             "([metrics reference](../reference/metrics.md#which-figure-decides)).", "",
             *markdown_table(["row", "figure", "bf16", "fp32", "p / Holm p", "outcome"], body), "",
             "## How it was made", "", *provenance_lines(command_line("spade.report")),
             f"- records: {shown_path(records_dir)} (shared with the oracle page; the page regenerates from them)", ""]
    text = "\n".join(lines)
    files: dict[str, Path] = {}
    if output_dir is not None:
        out = Path(output_dir)
        out.mkdir(parents=True, exist_ok=True)
        files["markdown"] = out / f"{settings.get('page', 'precision')}.md"
        files["markdown"].write_text(text + "\n")
    return text, files
