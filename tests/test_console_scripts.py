"""Console scripts beside ``python -m``: every script pyproject.toml declares imports and is callable,
stands for an entry point that exists, and runs it as ``python -m`` does (same argv handling, same exit status)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

tomllib = pytest.importorskip("tomllib")  # Python >= 3.11; on 3.10 the declarations are checked by the wheel test

REPO = Path(__file__).resolve().parents[1]
ENTRY_POINTS = ("train", "evaluate", "annotate", "report", "plan", "export", "sketch", "bench")


def declared_scripts() -> dict[str, str]:
    return tomllib.loads((REPO / "pyproject.toml").read_text())["project"]["scripts"]


CHECK = """
import importlib, json, sys
from pathlib import Path
problems = []
for name, target in json.loads(sys.argv[1]).items():
    module, _, attr = target.partition(":")
    func = getattr(importlib.import_module(module), attr, None)
    if not callable(func):
        problems.append(f"{name} -> {target}: not callable")
    if module != "spade.cli":  # a script of its own (e.g. spade.ros.__main__:cli): importable and callable
        continue
    entry = "spade." + name.removeprefix("spade-").replace("-", "_")  # the python -m module it stands for
    entry_module = importlib.import_module(entry)
    if callable(func) and func.__name__ != entry.rsplit(".", 1)[-1]:
        problems.append(f"{name} -> {target} runs {func.__name__}, not {entry}")
    if not callable(getattr(entry_module, "main", None)):
        problems.append(f"{entry} has no main()")
    if '__name__ == "__main__"' not in Path(entry_module.__file__).read_text():
        problems.append(f"{entry} is no python -m entry point")
print(json.dumps(problems))
"""


def test_every_entry_point_has_a_console_script_whose_target_imports_and_is_callable() -> None:
    scripts = declared_scripts()
    assert {f"spade-{name}": f"spade.cli:{name}" for name in ENTRY_POINTS}.items() <= scripts.items()
    # In a process of its own: importing the entry points imports torch, Hydra and MLflow, which set variables.
    done = subprocess.run([sys.executable, "-c", CHECK, json.dumps(scripts)], capture_output=True, text=True,
                          timeout=300, cwd=REPO)
    assert done.returncode == 0, done.stderr[-3000:]
    assert json.loads(done.stdout.splitlines()[-1]) == []


def test_a_console_script_runs_its_module_as_python_m_does(tmp_path: Path) -> None:
    """``spade-report`` with a store that does not exist: the entry point's own one-line error and exit 2."""
    env = {**{k: v for k, v in os.environ.items() if k not in ("MLFLOW_TRACKING_URI", "HYDRA_FULL_ERROR")},
           "SPADE_HOME": str(tmp_path)}
    code = "import sys; from spade.cli import report; sys.argv[0] = 'spade-report'; report()"
    store = f"tracking_uri=sqlite:///{tmp_path}/none/mlflow.db"
    done = subprocess.run([sys.executable, "-c", code, store], capture_output=True, text=True, timeout=120,
                          cwd=tmp_path, env=env)
    assert done.returncode == 2, done.stderr[-3000:]
    assert "error: tracking_uri=" in done.stderr and "no MLflow store" in done.stderr, done.stderr[-3000:]


def test_lightnings_advertising_is_not_printed_by_spade(capsys) -> None:  # noqa: ANN001
    import logging

    import lightning as L

    from spade.utils.console import LIGHTNING_RANK_ZERO, AdvertisingFilter, quiet_third_party_advertising

    quiet_third_party_advertising()
    quiet_third_party_advertising()  # once only
    logger = logging.getLogger(LIGHTNING_RANK_ZERO)
    assert sum(isinstance(f, AdvertisingFilter) for f in logger.filters) == 1
    records = []
    handler = logging.Handler()
    handler.emit = records.append  # type: ignore[method-assign]
    logger.addHandler(handler)
    try:
        L.Trainer(logger=False, enable_progress_bar=False, enable_model_summary=False)
        logger.info("GPU available: False")  # Lightning's other messages still pass
    finally:
        logger.removeHandler(handler)
    messages = [r.getMessage() for r in records]
    assert not any("litlogger" in m or "litmodels" in m for m in messages) and "GPU available: False" in messages
    assert "Tip" not in capsys.readouterr().err
