"""A SPADE checkpoint back as the LightningModule that wrote it (student or expert), loaded safely."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import lightning as L

from spade.models.modelfile import load_lightning, read_info
from spade.training.expert_module import ExpertModule
from spade.training.student_module import StudentModule


def load_module(ckpt_path: str | Path, **hparams: Any) -> L.LightningModule:
    """The :class:`StudentModule` or :class:`ExpertModule` of a checkpoint, by the role its ``spade`` entry
    records (:func:`spade.models.modelfile.load_lightning`: ``weights_only=True``); ``hparams`` replace the
    checkpoint's own (Lightning's ``load_from_checkpoint`` keywords: e.g. an expert's sampler)."""
    path = Path(ckpt_path)
    if not path.is_file():
        raise FileNotFoundError(f"ckpt_path={path} does not exist; pass a checkpoint written by python -m spade.train")
    role = read_info(path, checkpoint=True, required=False).get("role")
    if role == "student":
        return load_lightning(StudentModule, path, **hparams)
    if role == "expert":
        return load_lightning(ExpertModule, path, **hparams)
    raise ValueError(f"{path} is not a SPADE student or expert checkpoint (role {role!r})")
