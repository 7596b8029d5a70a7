"""The trained models SPADE ships, pinned by sha256, and the command that makes one from a checkpoint.

    python -m spade.models.shipped ckpt=PATH [name=cond_expert_L]

Why ship a model: the quickstart (``make quickstart``, 10 minutes on 2 CPU cores, install included) cannot also
train an expert worth learning from. The conditional expert that beats the heading template (``cpu_lite``, x0
prediction, 594 optimisation steps) takes 9-19 minutes on one core; the tiny one that fits the budget plans
worse than a straight line. So the package carries that expert, trained by the project's own
command (:data:`SHIPPED`'s ``rebuild``) on data the project generates, and the quickstart's Cond-DBC student
learns from it. Nothing is downloaded: the file is in the repository, like FID's feature weights.

A shipped file is a checkpoint of ``python -m spade.train`` with Lightning's resume state left out (optimiser
moments, schedulers, loops, callbacks: half of its 12.3 MB), so that it loads as the module it was trained in
(:func:`spade.models.modelfile.load_lightning`) but cannot resume a fit. Its ``spade`` entry keeps the role, the
network, the training windows, and gains ``shipped``: the rebuild command and the source checkpoint's MLflow
run. :func:`shipped_path` checks the pin before anyone uses the file, so that a changed or damaged file stops a
run with the fix named instead of quietly changing every figure that rests on it.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from spade.models.modelfile import ENTRY_KEY, ModelFileError, load_checkpoint
from spade.utils.hashing import file_sha256

__all__ = ["SHIPPED", "WEIGHTS_DIR", "ShippedModel", "ship_checkpoint", "shipped_path"]

WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"

# What a shipped checkpoint keeps: what load_from_checkpoint needs, and SPADE's entry.
KEEP = ("state_dict", "hyper_parameters", "hparams_name", ENTRY_KEY, "pytorch-lightning_version", "epoch", "global_step")


@dataclass(frozen=True)
class ShippedModel:
    """One shipped file: its name under :data:`WEIGHTS_DIR`, its pin and the command that trained it."""

    file: str
    sha256: str
    rebuild: str
    role: str

    @property
    def path(self) -> Path:
        return WEIGHTS_DIR / self.file


SHIPPED: dict[str, ShippedModel] = {
    # The scale=cpu conditional expert on the paper's binary start and goal discs (cpu_lite, x0, 11 epochs = 594
    # steps, seed 42): the guidance and paper rows on binary markers learn from it. Its figures as a planner beside
    # its student: docs/results/teacher.md (python -m spade.report table=teacher).
    "cond_expert_L": ShippedModel(
        file="cond_expert_L_cpu_lite_x0.ckpt",
        sha256="38eac1a15b252ec6ba92bb93739130e21eec5451ad763eca6ad7e91c630b2460",
        rebuild="python -m spade.train +experiment=cond_expert_L scale=cpu seed=42, then python -m "
                "spade.models.shipped ckpt=<its registered checkpoint> name=cond_expert_L",
        role="expert",
    ),
    # The teacher (docs/results/teacher.md): the same network on the quickstart's data with Gaussian start and goal
    # markers (the students' encoding, docs/results/encoding.md), 48 epochs of 54 steps, EMA 0.999, seed 42, its best epoch by validation
    # loss. The quickstart's student learns from it. Its figures: docs/results/teacher.md.
    "cond_expert_L_gaussian": ShippedModel(
        file="cond_expert_L_gaussian_cpu_lite_x0.ckpt",
        sha256="5dc7c060d0154e76dac7360c484948339ab37c62096833f54cadd03048be64ca",
        rebuild="python -m spade.train +experiment=teacher_L seed=42 threads=2, then python -m spade.models.shipped "
                "ckpt=<its best checkpoint> name=cond_expert_L_gaussian",
        role="expert",
    ),
}


def _model(name: str) -> ShippedModel:
    if name not in SHIPPED:
        raise KeyError(f"no shipped model {name!r}; the shipped ones are {sorted(SHIPPED)}")
    return SHIPPED[name]


def shipped_path(name: str) -> str:
    """The path of the shipped model ``name``, after checking that the file is there and hashes to its pin."""
    model = _model(name)
    path = model.path
    if not path.is_file():
        raise FileNotFoundError(f"the shipped model {name} ({path}) is missing: restore it from the repository "
                                f"(git checkout -- {path.relative_to(WEIGHTS_DIR.parents[1])}) or rebuild it: "
                                f"{model.rebuild}")
    sha = file_sha256(path)
    if sha != model.sha256:
        raise ModelFileError(f"the shipped model {name} ({path}) hashes to {sha[:12]}, not its pin "
                             f"{model.sha256[:12]}: the file changed, and every figure resting on it would too. "
                             f"Restore it from the repository, or rebuild it ({model.rebuild}) and update the pin "
                             f"in spade/models/shipped.py")
    return str(path)


def ship_checkpoint(ckpt: str | Path, out: str | Path, rebuild: str, role: str) -> dict[str, Any]:
    """Write ``ckpt`` without Lightning's resume state to ``out`` (see the module docstring); its sha256 and size."""
    checkpoint = load_checkpoint(ckpt)
    entry = checkpoint.get(ENTRY_KEY)
    if not isinstance(entry, dict) or entry.get("role") != role:
        raise ModelFileError(f"{ckpt} is not a SPADE {role} checkpoint (its '{ENTRY_KEY}' entry says role "
                             f"{(entry or {}).get('role')!r}); pass one written by python -m spade.train")
    kept = {key: checkpoint[key] for key in KEEP if key in checkpoint}
    kept[ENTRY_KEY] = {**entry, "shipped": {"rebuild": rebuild, "source_run": entry.get("mlflow_run_id")}}
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    partial = out.with_name(out.name + ".partial")
    torch.save(kept, partial)
    partial.replace(out)
    return {"out": str(out), "sha256": file_sha256(out), "bytes": out.stat().st_size}


def main(argv: list[str] | None = None) -> dict[str, Any]:
    options = {"ckpt": None, "name": "cond_expert_L"}
    for arg in sys.argv[1:] if argv is None else argv:
        key, _, value = arg.partition("=")
        if key not in options:
            raise SystemExit(f"unknown option {key!r}; options: ckpt=PATH, name={'|'.join(SHIPPED)}")
        options[key] = value
    if not options["ckpt"]:
        raise SystemExit("ckpt=PATH is required: the checkpoint to ship (e.g. a registered expert's)")
    model = _model(str(options["name"]))
    summary = ship_checkpoint(options["ckpt"], model.path, model.rebuild, model.role)
    print(f"wrote {summary['out']} ({summary['bytes'] / 1e6:.1f} MB): sha256 {summary['sha256']} (pin it as "
          f"SHIPPED[{options['name']!r}].sha256 in spade/models/shipped.py)")
    return summary


if __name__ == "__main__":
    main()
