"""Does a numerics lever keep the science? The medium BC student at the quickstart's scale (``+experiment=
enc_gaussian_L``: the default recipe's Gaussian markers) trained under each ``trainer.precision`` with the same
seeds; its test figures (planner APE, plausibility, ...) and fit time written as JSON, which
``python -m spade.bench ... speed_science=PATH`` puts on the speed page with a Welch test per figure.

``python -m spade.perf.precision_check out=PATH [seeds=0,1] [precisions=32-true,bf16-mixed] [OVERRIDE ...]``
(the overrides go to ``spade.train``'s config, e.g. ``trainer.max_epochs=2 data.train_dir=...``).
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any
from spade.experiments.run import train
from spade.utils.config import compose_config

#: spade.train overrides of every run: the medium BC row of the encoding table, tested on the held-out map only.
BASE_OVERRIDES: tuple[str, ...] = ("+experiment=enc_gaussian_L", "~also_test", "logger=none", "closed_loop=false",
                                   "test_untrained=false", "trainer.enable_progress_bar=false")


def train_once(precision: str, seed: int, overrides: Sequence[str], output_dir: Path) -> dict[str, Any]:
    """One run; its test figures (``test/*``), the precision the trainer resolved it to, and the fit's seconds."""
    cfg = compose_config("train", [*BASE_OVERRIDES, f"trainer.precision={precision}", f"seed={seed}",
                                   f"paths.output_dir={output_dir}", *overrides])
    t0 = time.perf_counter()
    metrics, objects = train(cfg)
    return {"precision": precision, "resolved": str(objects["trainer"].precision), "seed": seed,
            "seconds": time.perf_counter() - t0, "overrides": list(overrides),
            "metrics": {k: float(v) for k, v in metrics.items() if k.startswith("test/")}}


def main(argv: Sequence[str]) -> None:
    options = {k: v for k, _, v in (a.partition("=") for a in argv if a.split("=", 1)[0] in
                                    ("out", "seeds", "precisions"))}
    overrides = [a for a in argv if a.split("=", 1)[0] not in ("out", "seeds", "precisions")]
    if "out" not in options:
        raise SystemExit("error: out=PATH (a .json file) is required")
    out = Path(options["out"])
    seeds = [int(s) for s in options.get("seeds", "0,1").split(",")]
    precisions = options.get("precisions", "32-true,bf16-mixed").split(",")
    rows = json.loads(out.read_text()) if out.is_file() else []
    for seed in seeds:
        for precision in precisions:
            if any(r["seed"] == seed and r["precision"] == precision for r in rows):
                continue  # resumable: a finished run is kept
            rows.append(train_once(precision, seed, overrides, out.parent / f"run_{precision}_{seed}"))
            out.write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main(sys.argv[1:])
