"""The tutorial *Your own map, end to end* (docs/tutorials/own-map.md) runs as written: its shell
blocks are read from the page and run in order, at the page's own sizes, with a real ROS map from SPADE_MAPS_DIR as
``site.yaml`` (training and test sets cut from it by area), so that a command the page shows and the code no longer
accepts fails here, and so does a page whose recipe no longer teaches a student to beat the heading template."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PAGE = REPO / "docs" / "tutorials" / "own-map.md"

#: The user's map: Isaac Sim's Carter warehouse (the sizing table's map, docs/results/sizing.md).
SITE_MAP = "IsaacSim-ros_workspaces/carter_warehouse_navigation.yaml"


def shell_blocks(text: str) -> list[str]:
    return [m.group(1) for m in re.finditer(r"^ *```bash\n(.*?)^ *```", text, re.M | re.S)]


def dedent(block: str) -> str:
    lines = block.splitlines()
    pad = min(len(line) - len(line.lstrip()) for line in lines if line.strip())
    return "\n".join(line[pad:] for line in lines) + "\n"


def summary_ape(text: str, column: str) -> float:
    """The APE (the paper's extraction) of one predictor in a run's closing summary: its figures table's column
    (``student``, ``heading``), right-aligned under its name."""
    lines = text.splitlines()
    header = next((i for i, line in enumerate(lines) if line.startswith("  test figures")), None)
    assert header is not None, f"no figures table in the summary:\n{text[-3000:]}"
    name = re.search(rf"\s{column}(\s|$)", lines[header])
    assert name, f"no '{column}' column in the summary:\n{lines[header]}"
    end = name.start() + 1 + len(column)
    row = next(line for line in lines[header:] if line.startswith("  APE (cm)"))
    assert row[end - 1:end].strip(), f"no APE for '{column}':\n{lines[header]}\n{row}"
    return float(row[:end].split()[-1])


@pytest.mark.slow  # annotation on a real map, 10 epochs of a small student, its test, evaluation and a plan: minutes
@pytest.mark.timeout(1200)
def test_the_own_map_tutorial_runs_as_written(tmp_path: Path, maps_dir: Path) -> None:
    blocks = [dedent(b) for b in shell_blocks(PAGE.read_text())]
    site = maps_dir / SITE_MAP
    assert site.is_file(), f"{site} is missing from SPADE_MAPS_DIR"
    replacements = [(r"\bsite\.yaml\b", str(site)), (r"data/other/test", "data/site/test")]
    wanted = {
        "templates": next(b for b in blocks if "spade.annotate maps=[site.yaml]" in b and "split=area:train" in b),
        "verify": next(b for b in blocks if "spade.data.verify" in b),
        "train": next(b for b in blocks if "+experiment=t1_small_bc_L" in b and "data=own" in b),
        "use": next(b for b in blocks if "spade.evaluate" in b and "spade.plan" in b),
    }
    env = {**{k: v for k, v in os.environ.items() if k not in ("MLFLOW_TRACKING_URI", "HYDRA_FULL_ERROR")},
           "SPADE_HOME": str(tmp_path), "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}

    # the page defines the window settings once (W=...), in the block before the split commands that use them
    prefix = next(line for b in blocks for line in b.splitlines() if line.startswith("W="))

    def run(name: str, block: str) -> subprocess.CompletedProcess:
        for pattern, repl in replacements:
            block = re.sub(pattern, repl, block)
        block = block.replace("python -m", f"{sys.executable} -m")
        return subprocess.run(["bash", "-c", "set -e\n" + prefix + "\n" + block], capture_output=True, text=True,
                              timeout=900, cwd=tmp_path, env=env)

    for name in ("templates", "verify", "train"):
        done = run(name, wanted[name])
        assert done.returncode == 0, f"{name}:\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
        if name == "train":
            found = re.search(r"best checkpoint\s*:\s*(\S+\.ckpt)", done.stdout + done.stderr)
            assert found, done.stdout[-3000:]
            checkpoint = found.group(1)
            # the page's sizes teach the student a preference: it beats the heading template on the test part
            student, template = summary_ape(done.stdout, "student"), summary_ape(done.stdout, "heading")
            assert student < template, f"student {student} cm vs heading template {template} cm APE"
    assert (tmp_path / "data/site/train/preview.png").is_file()
    # Evaluate the student, then plan with it: the plan may find no path from the page's pose on another map (exit
    # 1, its picture written all the same), but the command line must be accepted (a user error exits 2).
    use = wanted["use"].replace("student.ckpt", checkpoint)
    evaluate, plan = [line for line in use.splitlines() if line.strip()]
    done = run("evaluate", evaluate)
    assert done.returncode == 0 and "ape_cm" in done.stdout, f"{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
    done = run("plan", plan)
    assert done.returncode in (0, 1), f"{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
    assert (tmp_path / "plan.png").is_file()
