"""Reliability, third round (issue 51): the wrong cases of the probe, reproduced, and the new behaviour.

- default output paths are checked as explicit ones are (``spade.export``'s export beside the checkpoint,
  ``spade.report``'s pages, ``spade.bench``'s JSON), and an empty path is refused instead of the filesystem root;
- a dataset manifest without its ``manifest_sha256`` is refused by ``verify`` and by loading;
- an ONNX graph carrying a copy of a real export's ``spade`` metadata is refused by the planner (torch and
  torch-free), ``spade.plan`` and the sketch server; an export from before the check opens with a warning.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from factories import write_synthetic
from test_reliability_outputs import digest, one_error_line, run_main, student_checkpoint  # noqa: F401 - a fixture

REPO = Path(__file__).resolve().parents[1]


# -- 2. a manifest without its checksum ------------------------------------------------------------------------------
def _strip_checksum(root: Path) -> Path:
    """The probe's edit: resolution and the generator record changed, ``manifest_sha256`` deleted."""
    manifest = root / "manifest.json"
    raw = json.loads(manifest.read_text())
    raw["resolution"] = 0.1
    raw["generator"]["seed"] = 999
    del raw["manifest_sha256"]
    manifest.write_text(json.dumps(raw))
    return manifest


def test_a_manifest_without_its_checksum_is_refused_by_verify_and_loading(tmp_path: Path) -> None:
    """Issue 51: a manifest whose resolution and generator record were edited and whose ``manifest_sha256`` was
    deleted verified "OK" and loaded. Now both refuse it, naming the file and the fix (regenerate)."""
    from spade.data import DatasetError, PathDataset
    from spade.data.verify import verify

    root = tmp_path / "ds"
    write_synthetic(root, n=4)
    assert verify(root) == [] and len(PathDataset(root)) == 4  # as written: sound
    manifest = _strip_checksum(root)
    (problem,) = verify(root)
    assert str(manifest) in problem and "no manifest_sha256" in problem and "Re-generate the dataset" in problem
    with pytest.raises(DatasetError, match="no manifest_sha256") as info:
        PathDataset(root)
    assert str(manifest) in str(info.value)


@pytest.mark.slow  # a python -m spade.data.verify process
def test_verify_command_reports_the_missing_checksum(tmp_path: Path) -> None:
    root = tmp_path / "ds"
    write_synthetic(root, n=3)
    _strip_checksum(root)
    proc = subprocess.run([sys.executable, "-m", "spade.data.verify", str(root)], cwd=REPO, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert "OK" not in proc.stdout and "no manifest_sha256" in proc.stdout
