"""The shape of the code around a run, measured in two checkouts: ``python -m spade.perf.code_shape --before REV``.

What the periphery issue asked to report before and after its refactor, measured, never typed:

* the SPADE modules ``import spade.train`` loads (what a ``--help`` or a config error pays before any work);
* the wall time of ``python -m spade.train --help`` (median of ``--runs`` fresh processes);
* non-blank lines of ``spade/experiments/``, of the code that records a run in MLflow (``tracking`` folders,
  ``registry.py``, ``progress_picture.py``) and of the code that checks configs (``checks`` folders,
  ``*checks*.py``, ``preflight.py``, ``*options.py``, ``refusals.py``);
* the ``MlflowClient(`` constructions in the package;
* for each headline metric, the package files that spell its name as a string literal, and the spellings of the
  tail's label (``> 20 cm`` against ``>20 cm``).

``--before`` is checked out into a temporary ``git worktree`` (removed afterwards); "after" is this checkout. With
``--output`` the page is written there (``code_shape.md``) with its command, commits, date, machine and wall time.
"""

from __future__ import annotations

import argparse
import datetime
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from spade.utils.provenance import REPO_ROOT, command_line, machine

__all__ = ["measure", "render", "main"]

METRIC_NAMES = ("ape_cm", "over_20cm_rate", "hd19", "fid", "failure_rate", "plausibility_cm", "commit_rate",
                "floor_ratio", "success_rate")
"""Headline figures whose spellings are counted."""
TAIL_LABELS = ("> 20 cm", ">20 cm")
_COUNT_MODULES = ("import sys, spade.train; "
                  "print(sum(1 for m in sys.modules if m == 'spade' or m.startswith('spade.')))")


def _python_files(root: Path) -> list[Path]:
    """The package's Python files, but this instrument (whose patterns would count themselves)."""
    return sorted(p for p in (root / "spade").rglob("*.py")
                  if "__pycache__" not in p.parts and p.relative_to(root / "spade").as_posix() != "perf/code_shape.py")


def _lines(path: Path) -> int:
    return sum(1 for line in path.read_text(errors="replace").splitlines() if line.strip())


def _is_tracking(rel: Path) -> bool:
    return "tracking" in rel.parts[:-1] or rel.name in ("registry.py", "progress_picture.py")


def _is_checks(rel: Path) -> bool:
    return ("checks" in rel.parts[:-1] or "checks" in rel.stem or rel.name in ("preflight.py", "refusals.py")
            or rel.stem.endswith("options"))


def _run(root: Path, args: list[str]) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(root)}  # this checkout's package, not an installed one
    return subprocess.run([sys.executable, *args], cwd=root, env=env, capture_output=True, text=True, timeout=300)


def measure(root: str | Path, runs: int = 3) -> dict[str, object]:
    """The figures of the module docstring for the checkout at ``root``."""
    root = Path(root)
    files = _python_files(root)
    rel = {p: p.relative_to(root / "spade") for p in files}
    texts = {p: p.read_text(errors="replace") for p in files}
    counted = _run(root, ["-c", _COUNT_MODULES])
    if counted.returncode != 0:
        raise RuntimeError(f"import spade.train failed in {root}: {counted.stderr.strip().splitlines()[-1:]}")
    seconds = []
    for _ in range(runs):
        t0 = time.perf_counter()
        helped = _run(root, ["-m", "spade.train", "--help"])
        seconds.append(time.perf_counter() - t0)
        if helped.returncode != 0:
            raise RuntimeError(f"python -m spade.train --help failed in {root}: {helped.stderr.strip()[-300:]}")
    construction = re.compile(r"(?<![`\w])MlflowClient\(")
    names = {}
    for name in METRIC_NAMES:
        literal = re.compile(rf"[\"'/]{re.escape(name)}[\"']")
        names[name] = sum(1 for p in files if literal.search(texts[p]))
    return {
        "modules_imported_by_spade_train": int(counted.stdout.strip().splitlines()[-1]),
        "train_help_seconds": statistics.median(seconds),
        "lines_experiments": sum(_lines(p) for p in files if rel[p].parts[0] == "experiments"),
        "lines_tracking": sum(_lines(p) for p in files if _is_tracking(rel[p])),
        "lines_checks": sum(_lines(p) for p in files if _is_checks(rel[p])),
        "lines_package": sum(_lines(p) for p in files),
        "mlflow_client_constructions": sum(len(construction.findall(texts[p])) for p in files),
        "files_spelling_metric": names,
        "tail_label_spellings": {label: sum(texts[p].count(label) for p in files) for label in TAIL_LABELS},
    }


def _git(*args: str) -> str:
    return subprocess.run(["git", "-C", str(REPO_ROOT), *args], capture_output=True, text=True, check=True,
                          timeout=120).stdout.strip()


def render(before: dict, after: dict, before_rev: str, after_rev: str, command: str, seconds: float) -> str:
    """The page: one row per figure, before and after."""
    rows = [
        ("SPADE modules loaded by `import spade.train`", "modules_imported_by_spade_train", "d"),
        ("`python -m spade.train --help` (s, median)", "train_help_seconds", ".2f"),
        ("lines of `spade/experiments/`", "lines_experiments", "d"),
        ("lines recording a run in MLflow", "lines_tracking", "d"),
        ("lines checking configs", "lines_checks", "d"),
        ("lines of the package", "lines_package", "d"),
        ("`MlflowClient(` constructions", "mlflow_client_constructions", "d"),
    ]
    lines = ["# The shape of the code around a run, before and after", "",
             "Measured by `spade.perf.code_shape` in two checkouts of the repository (module docstring for what each "
             "figure counts). Lines are non-blank lines of Python under `spade/`.", "",
             f"| figure | before ({before_rev}) | after ({after_rev}) |", "|---|---:|---:|"]
    lines += [f"| {label} | {format(before[key], fmt)} | {format(after[key], fmt)} |" for label, key, fmt in rows]
    for name in METRIC_NAMES:
        lines.append(f"| files spelling the metric name `{name}` | {before['files_spelling_metric'][name]} | "
                     f"{after['files_spelling_metric'][name]} |")
    for label in TAIL_LABELS:
        lines.append(f"| spellings of the tail label `{label}` | {before['tail_label_spellings'][label]} | "
                     f"{after['tail_label_spellings'][label]} |")
    lines += ["", "Provenance:", "", f"- command: `{command}`", f"- commits: before {before_rev}, after {after_rev}",
              f"- date: {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC",
              f"- machine: {machine()}", f"- wall time: {seconds:.0f} s", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m spade.perf.code_shape", description=__doc__.splitlines()[0])
    parser.add_argument("--before", required=True, help="the git revision to compare with (e.g. a commit id)")
    parser.add_argument("--runs", type=int, default=3, help="fresh processes timed for --help (median)")
    parser.add_argument("--output", default=None, help="folder to write code_shape.md into (default: print only)")
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    try:
        before_rev = _git("rev-parse", "--short=12", args.before)
    except subprocess.CalledProcessError:
        print(f"error: --before={args.before} is not a revision of this repository; pass a commit id or tag",
              file=sys.stderr)
        return 2
    after_rev = _git("rev-parse", "--short=12", "HEAD") + ("+changes" if _git("status", "--porcelain",
                                                                           "--untracked-files=no") else "")
    with tempfile.TemporaryDirectory() as tmp:
        tree = Path(tmp) / "before"
        _git("worktree", "add", "--detach", str(tree), before_rev)
        try:
            before = measure(tree, args.runs)
        finally:
            _git("worktree", "remove", "--force", str(tree))
    after = measure(REPO_ROOT, args.runs)
    page = render(before, after, before_rev, after_rev, command_line("spade.perf.code_shape"),
                  time.perf_counter() - t0)
    print(page)
    if args.output:
        out = Path(args.output)
        out.mkdir(parents=True, exist_ok=True)
        (out / "code_shape.md").write_text(page)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
