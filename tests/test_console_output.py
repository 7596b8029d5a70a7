"""The console: one progress line per stage, not a bar per validation loader; the annotate summary warns when a
test part has few scenarios, with the uncertainty that implies; the quickstart's console has no duplicated line
(Lightning's lines were printed twice, plain and Hydra-formatted) and no line over 120 characters once the run has
started; no Lightning test table; the closing summary leads with the deciding figure (the planner's APE, then its
tail), in per cent throughout, with one ``spade.plan`` syntax."""

from __future__ import annotations

import logging
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
WIDTH = 120


def test_the_console_shows_no_bar_per_validation_loader(capsys) -> None:
    import lightning as L
    import torch
    from lightning.pytorch.demos.boring_classes import BoringModel, RandomDataset
    from torch.utils.data import DataLoader

    from spade.utils.console import stage_progress_bar

    class TwoLoaders(BoringModel):
        def validation_step(self, batch, batch_idx, dataloader_idx=0):  # type: ignore[no-untyped-def]
            return super().validation_step(batch, batch_idx)

        def val_dataloader(self):  # type: ignore[no-untyped-def]
            return [DataLoader(RandomDataset(32, 8)), DataLoader(RandomDataset(32, 8))]

    bar = stage_progress_bar(refresh_rate=1)
    trainer = L.Trainer(max_epochs=2, limit_train_batches=4, callbacks=[bar], logger=False,
                        enable_checkpointing=False, enable_model_summary=False, accelerator="cpu")
    torch.manual_seed(0)
    trainer.fit(TwoLoaders())
    captured = capsys.readouterr()
    err = captured.out + captured.err
    assert "Epoch 1" in err and "Validation" not in err and "Sanity Checking" not in err
    assert type(stage_progress_bar(enabled=False)).__name__ == "Callback"  # trainer.enable_progress_bar=false


def test_a_small_test_part_gets_a_warning_with_its_uncertainty() -> None:
    from spade.annotation.run import FEW_SCENARIOS, few_scenarios_warning, is_test_part

    text = few_scenarios_warning(10, True)
    assert text and "only 10 scenarios" in text and "+-31 percentage points" in text
    assert few_scenarios_warning(FEW_SCENARIOS, True) is None and few_scenarios_warning(10, False) is None
    assert is_test_part({"split": "test"}, None, Path("data/x")) and is_test_part({}, None, Path("data/own_test"))
    assert not is_test_part({}, None, Path("data/own_train"))


# -- the quickstart's console ----------------------------------------------------------------------------------------
def _bar(line: str) -> bool:
    """A progress bar's redraw (tqdm's: ``Epoch 1:  40%|####  | 4/10 [...]``), which repeats by design."""
    return bool(re.search(r"\d+(/\d+|/\?) \[[\d:?]+<", line)) or line.startswith(("Training:", "Testing"))


def _summary_metrics() -> dict[str, float]:
    """A quickstart's test as logged: the student, three baselines, the untrained student, the floor and closed loop."""
    m = {"test/failure_rate": 0.0, "test/ape_cm": 108.94318389892578, "test/hd19": 43.0, "test/over_20cm_rate": 1.0,
         "test/planner/ape_cm": 8.22214698791504, "test/planner/over_20cm_rate": 0.11627907305955887,
         "test/planner/low_confidence_rate": 0.0, "test/planner/ape_over_floor": 2.581,
         "test/planner/plausibility_cm": 6.35205078125, "test/planner/commit_rate": 0.5348837375640869,
         "test/floor_cm": 3.1856281757354736, "test/ceiling/planner/ape_cm": 3.18,
         "test/ceiling/planner/ape_over_floor": 1.0,
         "test/ceiling/planner/plausibility_cm": 1.73, "test/ceiling/planner/commit_rate": 0.53,
         "test/demo_target/planner/ape_cm": 1.17, "test/scenarios": 17.0, "untrained/planner/ape_cm": 28.04,
         "untrained/planner/over_20cm_rate": 0.51, "untrained/ape_cm": 108.9, "closed_loop/episodes": 9.0}
    for name, ape in (("straight", 29.72), ("shortest", 28.46), ("heading", 15.21)):
        base = f"test/baseline/{name}/"
        m.update({base + "planner/ape_cm": ape, base + "planner/over_20cm_rate": 0.5348837375640869,
                  base + "ape_cm": ape + 0.5, base + "hd19": 7.0, base + "failure_rate": 0.0,
                  base + "over_20cm_rate": 0.58, base + "planner/plausibility_cm": 24.6,
                  base + "planner/commit_rate": 0.0465})
    driven = {"success_rate": 1.0, "collision_rate": 0.0, "timeout_rate": 0.0, "no_plan_rate": 0.0, "ape_cm": 58.87,
              "plausibility_cm": 48.41, "commit_rate": 0.0, "mode_switches": 0.5, "replans": 6.0, "plan_ms": 47.6}
    for prefix in ("", "baseline/shortest/", "baseline/heading/", "followed/", "demonstration/"):
        m.update({f"closed_loop/{prefix}{k}": v for k, v in driven.items()})
    return m


def _check_summary(text: str, checkpoint: str) -> None:
    """What the closing summary of a student's run must be (see the module's docstring)."""
    lines = text.splitlines()
    assert max(len(line) for line in lines) <= WIDTH, max(lines, key=len)
    table = lines.index(next(line for line in lines if line.strip().startswith("test figures")))
    assert lines[table + 1].split()[:3] == ["planner", "APE", "(cm)"]  # the deciding figure first,
    assert lines[table + 2].split()[:2] == ["planner", ">20"]  # then its tail
    assert "student" in lines[table] and "heading" in lines[table] and "untrained" in lines[table]
    tail = lines[table + 2].split()[3:]
    assert tail and all(cell.endswith("%") for cell in tail), lines[table + 2]  # shares in per cent
    assert not re.search(r"\b(rate|over_20cm_rate)=0\.\d", text)  # no share as a fraction beside per cents
    verdict = " ".join(text[text.index("  verdict "):].split())  # the verdict's lines, their wrapping undone
    assert "deciding figure: the planner's APE" in verdict and re.search(r">20 cm \d+ % vs \d+ %", verdict)
    assert text.count("python -m spade.plan") == 1  # one syntax, the one that works from any folder
    plan = text[text.index("python -m spade.plan"):]
    assert f"model={checkpoint}" in " ".join(plan.replace(" \\\n", " ").split()[:7])


def test_the_closing_summary_fits_120_columns_and_leads_with_the_deciding_figure(spade_home: Path) -> None:
    from spade.tracking.summary import run_summary
    from spade.tracking.runs import RunRef
    from training_helpers import compose_row

    from omegaconf import open_dict

    cfg = compose_row("quickstart", spade_home, "logger=none")
    with open_dict(cfg):
        cfg.paths.mlflow_tracking_uri = "sqlite:////home/ada/src/spade/logs/mlflow.db"
    # a user's clone (the test's own folder is longer than most): the path is printed whole, after a continuation
    checkpoint = "/home/ada/src/spade/logs/runs/train/2026-12-07_14-06-31_b9866b512a3f/checkpoints/epoch001.ckpt"
    run = RunRef(cfg.paths.mlflow_tracking_uri, "1", "e0f71a8076c04d00988c7902299a246a", "quickstart",
                 "runs:/e0f71a8076c04d00988c7902299a246a/model")
    text = run_summary(cfg, _summary_metrics(), [(0, 1.0, 0.4), (1, 0.8, 0.2)], checkpoint, run)
    _check_summary(text, checkpoint)
    assert "logged model     : runs:/e0f71a8076c04d00988c7902299a246a/model" in text
    assert "Nav2-like shortest path" in text and "closed loop: 9 scenarios" in text
    assert "floor            : 3.19 cm" in text and "BC ceiling       : planner APE 3.18 cm" in text


def test_log_records_are_printed_once_and_wrapped_within_120_columns(capsys) -> None:  # noqa: ANN001
    """Lightning's own console handler ("INFO: ...") is removed once the root logger has handlers (a command's
    task): its records reach the console once, through the root's handler, wrapped by SPADE's console format."""
    import lightning  # noqa: F401 - adds its handler to the "lightning" logger

    from spade.utils.console import ConsoleFormatter, ConsoleHandler, lightning_logs_once, quiet_lightning_info

    root, lightning_logger = logging.getLogger(), logging.getLogger("lightning")
    plain = logging.StreamHandler(sys.stderr)  # what import lightning adds
    lightning_logger.addHandler(plain)
    console = ConsoleHandler(sys.stdout)
    console.setFormatter(ConsoleFormatter())
    old_level, old_handlers = root.level, list(root.handlers)
    for handler in old_handlers:  # an earlier test's handlers (a command's task) may hold a stream closed since
        root.removeHandler(handler)
    root.addHandler(console)
    root.setLevel(logging.INFO)
    try:
        lightning_logs_once()
        assert plain not in lightning_logger.handlers and lightning_logger.propagate
        rank_zero = logging.getLogger("lightning.pytorch.utilities.rank_zero")
        rank_zero.info("GPU available: False, used: False")
        with quiet_lightning_info():
            rank_zero.info("GPU available: False, used: False")  # a second trainer's: left out
        rank_zero.info("Restoring states from the checkpoint path at " + "/very/long/folder" * 8 + "/epoch000.ckpt "
                       "and then some words that run on past the console's width, to be wrapped under the message")
        rank_zero.info("Restoring states from the checkpoint path at /runs/x/epoch001.ckpt")
        rank_zero.info("Loaded model weights from the checkpoint at /runs/x/epoch001.ckpt")  # the same path again
    finally:
        root.removeHandler(console)
        for handler in old_handlers:
            root.addHandler(handler)
        root.setLevel(old_level)
        lightning_logger.removeHandler(plain)
    captured = capsys.readouterr()
    out = captured.out.splitlines()
    assert "GPU available" not in captured.err  # Lightning's own handler printed nothing
    assert sum("GPU available" in line for line in out) == 1 and re.match(r"\[\d\d:\d\d:\d\d\]\[INFO\] GPU", out[0])
    long_word = "/very/long/folder" * 8 + "/epoch000.ckpt"
    assert all(len(line) <= WIDTH for line in out if long_word not in line) and len(out) >= 3
    assert any(line.startswith(" " * 17) for line in out)  # wrapped under the message
    assert sum("/runs/x/epoch001.ckpt" in line for line in out) == 1 and "Loaded model weights" not in captured.out


def test_the_progress_bar_fits_120_columns_without_the_run_tag() -> None:
    import io

    from lightning.pytorch.callbacks.progress.tqdm_progress import Tqdm

    from spade.utils.console import CONSOLE_WIDTH, _narrow

    bar = _narrow(Tqdm(total=10, file=io.StringIO()))  # a file: no width of its own
    assert bar.ncols == CONSOLE_WIDTH
    postfix = "loss_bc=0.640, loss_dm=0.873, margin_active=1.000, loss=0.902, " * 2
    assert len(Tqdm.format_meter(3, 10, 1.0, ncols=bar.ncols, prefix="Epoch 1", postfix=postfix)) <= WIDTH


@pytest.mark.slow  # the quickstart at tiny scale in a process of its own: about 1.5 minutes on a quiet 2-core machine
@pytest.mark.timeout(900)
def test_the_quickstart_console_has_no_duplicated_line_and_none_over_120_columns() -> None:
    env = {k: v for k, v in os.environ.items() if k not in ("MLFLOW_TRACKING_URI", "HYDRA_FULL_ERROR")}
    # a short SPADE_HOME: the paths the summary prints (the checkpoint's, whole) are then as long as a user's
    with tempfile.TemporaryDirectory(prefix="q", dir="/tmp") as home:
        out_file = Path(home) / "console.txt"
        with open(out_file, "w") as sink:
            done = subprocess.run([sys.executable, "-m", "spade.train", "+experiment=quickstart", "scale=tiny",
                                   "closed_loop=true"], cwd=REPO, env={**env, "SPADE_HOME": home,
                                                                        "PYTHONUNBUFFERED": "1"},
                                  stdout=sink, stderr=subprocess.STDOUT, text=True, timeout=840)
        out = out_file.read_text()
        assert done.returncode == 0, out[-4000:]
        lines = [line.rstrip() for line in re.split(r"[\r\n]", out) if line.strip()]
        too_long = [line for line in lines if len(line) > WIDTH]
        assert not too_long, too_long
        printed = [line for line in lines if not _bar(line)]
        duplicated = sorted({line for line in printed if printed.count(line) > 1})
        assert not duplicated, duplicated
        assert "Test metric" not in out and "DataLoader 0  " not in out  # no Lightning test table
        assert not any(line.startswith("INFO: ") for line in lines)  # Lightning's own handler: gone
        assert "GPU available" in out  # its lines still printed (once, in SPADE's console format)
        summary = out[out.index("run quickstart finished"):]
        checkpoint = re.search(r"best checkpoint  : (\S+)", summary).group(1)
        assert checkpoint.startswith(home) and Path(checkpoint).is_file()
        _check_summary(summary, checkpoint)
        assert re.search(r"logged model     : runs:/[0-9a-f]{32}/model", summary)


@pytest.mark.parametrize("student_ape, outcome", [
    (12.1, "the student beats the Nav2-like shortest path (15.3 cm) and the heading template (19.0 cm, success 95 %)"),
    (18.4, "the student beats the heading template (19.0 cm, success 95 %) but loses to the Nav2-like shortest path "
           "(15.3 cm)")])
def test_the_closed_loop_table_ends_with_its_verdict_within_120_columns(student_ape: float, outcome: str) -> None:
    from spade.tracking.summary import closed_loop_lines

    m = {"closed_loop/episodes": 40.0, "test/failure_rate": 0.0}
    for prefix, ape, success in (("", student_ape, 1.0), ("baseline/shortest/", 15.3, 1.0),
                                 ("baseline/heading/", 19.0, 0.95), ("followed/", 4.46, 1.0)):
        m.update({f"closed_loop/{prefix}ape_cm": ape, f"closed_loop/{prefix}success_rate": success,
                  f"closed_loop/{prefix}mode_switches": 0.64})
    lines = closed_loop_lines(m)
    assert max(len(line) for line in lines) <= WIDTH, max(lines, key=len)
    start = next(i for i, line in enumerate(lines) if line.lstrip().startswith("closed loop "))
    assert start > 4  # under the table's rows: a header, the student, two baselines, the followed demonstration
    verdict = " ".join(" ".join(lines[start:]).split())
    assert verdict.startswith(f"closed loop : success 100 %, APE {student_ape:.1f} cm, 0.64 mode switches per "
                              "scenario;"), verdict
    assert outcome in verdict and "the demonstration followed drives at 4.5 cm" in verdict
