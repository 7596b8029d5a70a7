"""A whole table from an empty MLflow store: ``+experiment=ablation_finetune`` trains its prerequisites (an expert,
two pretrained students) and its three rows, and ``python -m spade.report`` prints Table 2 with every row filled."""

from __future__ import annotations

import csv
import os
import subprocess
import sys
from pathlib import Path

import pytest

from spade.tracking.tables import TABLES
from spade.tracking.predictors import TOP_LEVEL_FILTER

REPO = Path(__file__).resolve().parents[1]
# One "epoch" of 2 training batches, one validation batch (so that optimized_metric is logged), one test batch.
CAPPED = ("trainer.max_epochs=1", "++trainer.limit_train_batches=2", "++trainer.limit_val_batches=1",
          "++trainer.limit_test_batches=1", "++trainer.num_sanity_val_steps=0")
SAME_KEYS = {"test/ape_cm", "test/hd19", "test/failure_rate", "model/params"}


def _python(args: list[str], home: Path, timeout: int) -> str:
    env = {**os.environ, "SPADE_HOME": str(home), "PYTHONUNBUFFERED": "1"}
    env.pop("MLFLOW_TRACKING_URI", None)
    proc = subprocess.run([sys.executable, "-m", *args], cwd=REPO, env=env, capture_output=True, text=True,
                          timeout=timeout)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-4000:]
    return proc.stdout


def _table2_end_to_end(home: Path, *train_overrides: str) -> None:
    _python(["spade.train", "+experiment=ablation_finetune", "scale=tiny", "seeds=[42]",
             "trainer.enable_progress_bar=false", *train_overrides], home, timeout=1800)
    out = _python(["spade.report", "table=table2"], home, timeout=300)

    table = TABLES["table2"]
    lines = out.split("| approach |", 1)[1].split("\n\n", 1)[0].splitlines()[2:]
    body = [line for line in lines if not line.startswith("| reference:")]
    assert len(body) == 3 and not any("missing" in line for line in body), out
    # The classical baselines of the rows' test set are reference rows of the table.
    assert sum(line.startswith("| reference:") for line in lines) == 3, out
    assert "3 of 3 rows have a finished run" in out
    assert "Aug. BC fine-tuned with Cond-DBC vs SKIPP BC fine-tuned" in out
    reports = home / "logs" / "reports"
    with open(reports / "table2.csv") as fh:
        rows = list(csv.DictReader(fh))
    assert [r["row"] for r in rows] == table.rows and all(r["status"] == "ok" for r in rows)
    assert all(r["hd19"] != "" and float(r["params"]) > 1e6 for r in rows)  # medium students
    assert (reports / "table2.png").stat().st_size > 10_000

    # The MLflow UI view: one experiment per table, run names = row names, the same metric keys in every row.
    from mlflow import MlflowClient

    client = MlflowClient(tracking_uri=f"sqlite:///{home}/logs/mlflow.db")
    exp = client.get_experiment_by_name("table2")
    assert "ablation_finetune" in exp.tags["mlflow.note.content"]
    runs = client.search_runs([exp.experiment_id], filter_string=TOP_LEVEL_FILTER)
    assert sorted(r.info.run_name for r in runs) == sorted(table.rows)
    assert all(SAME_KEYS <= set(r.data.metrics) and r.info.status == "FINISHED" for r in runs)
    assert all(r.data.tags["table"] == "table2" and r.data.tags["row"] == r.info.run_name for r in runs)
    prerequisites = client.search_runs([client.get_experiment_by_name("table1").experiment_id], filter_string=TOP_LEVEL_FILTER)
    assert sorted(r.info.run_name for r in prerequisites) == ["cond_expert_L", "t1_medium_bc_L", "t1_medium_conddbc_L"]


@pytest.mark.slow  # whole tables in spade.train processes; every row in-process: test_experiments_compose.py
def test_table2_from_an_empty_store_full_tiny_scale(tmp_path: Path) -> None:
    """Exactly the README's commands at tiny scale (2 epochs per training). The capped-steps path through a table
    is the whole-composition test's below."""
    _table2_end_to_end(tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize("composition,key,rows", [
    ("ablation_scratch", "table3", None),
    # Table 1's L half (its 9 students and 2 experts): the U half runs the same code on the other shape's data,
    # which Tables 2 and 3 train and test on; every U row composes and instantiates in test_experiments_compose.py.
    ("table1", "table1", "[t1_*_L,cond_expert_L,uncond_expert_L]"),
])
def test_whole_table_composition_from_an_empty_store(composition: str, key: str, rows: str | None,
                                                      tmp_path: Path) -> None:
    """The other two table compositions, capped steps: every row launched (and its prerequisite) runs, and the
    report fills them."""
    _python(["spade.train", f"+experiment={composition}", "scale=tiny", "seeds=[42]",
             "trainer.enable_progress_bar=false", *CAPPED, *([f"rows={rows}"] if rows else [])], tmp_path,
            timeout=2400)
    out = _python(["spade.report", f"table={key}", "scale=tiny", "chart=false"], tmp_path, timeout=300)
    table = TABLES[key]
    launched = [r for r in table.rows if rows is None or r.endswith("_L")]
    assert f"{len(launched)} of {len(table.rows)} rows have a finished run" in out, out
    with open(tmp_path / "logs" / "reports" / f"{key}.csv") as fh:
        status = {r["row"]: r["status"] for r in csv.DictReader(fh)}
    assert sorted(status) == sorted(table.rows)
    assert {r for r, s in status.items() if s == "ok"} == set(launched), status
