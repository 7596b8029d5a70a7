"""A teacher's committed plans as labels: the states of a site nobody sketched, labelled by a diffusion expert.

Diffusion-based augmentation read literally (docs/method.md, "What can a teacher teach?"): for each state of an unlabelled dataset the expert
draws ``samples`` (K) paths, the planner decodes each, and their medoid (the minimum-Bayes-risk reading,
:func:`spade.metrics.preference.medoid_path`, the same reading as the teacher's planner figures) becomes the state's
demonstration. A student then trains by BC on its own demonstrations plus these labels
(``data.unlabelled_labels=true data.unlabelled_teacher=CKPT``; ``spade.train`` calls :func:`label_unlabelled` on its
data module before fitting): the plainest way for one large teacher to pass what it
knows about a site's maps to a small per-site student.

The labelled set is a SPADE dataset written beside the unlabelled one (``<unlabelled>.teacher-<digest>``), keyed by
the teacher checkpoint's sha256, K, the number of states and the encoding, so that it is sampled once and reused by
every seed and row. The generator's own alternatives are not copied (they are the oracle's knowledge, not the
teacher's). A state whose K paths all fail to decode is left out; the manifest counts them.
"""

from __future__ import annotations

import hashlib
import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from spade.data.format import DatasetError
from spade.data.packing import unpack_bits, unpack_two_bit
from spade.data.path_dataset import PathDataset
from spade.data.polyline import resample_polyline
from spade.data.rasterize import draw_polyline
from spade.data.writer import DatasetWriter
from spade.metrics.path_metrics import PathMetrics
from spade.metrics.preference import medoid_path
from spade.training.loading import load_module
from spade.training.teacher import sample_maps

__all__ = ["TeacherLabels", "teacher_labels_dir", "write_teacher_labels", "ensure_teacher_labels", "label_unlabelled"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TeacherLabels:
    """What :func:`write_teacher_labels` wrote: the dataset, how many states it labelled, how many it left out (every
    sample failed to decode) and the seconds it took."""

    path: Path
    labelled: int
    left_out: int
    seconds: float


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def teacher_labels_dir(unlabelled_dir: str | Path, teacher_ckpt: str | Path, samples: int, states: int,
                       encoding: str) -> Path:
    """Where the teacher's labels of the first ``states`` states of ``unlabelled_dir`` live (beside it)."""
    source = Path(unlabelled_dir)
    key = hashlib.sha256(f"{_sha256(Path(teacher_ckpt))}|{samples}|{states}|{encoding}".encode()).hexdigest()[:12]
    return source.parent / f"{source.name}.teacher-{key}"


@torch.no_grad()
def write_teacher_labels(teacher_ckpt: str | Path, unlabelled_dir: str | Path, out_dir: str | Path,
                         samples: int = 4, states: int | None = None, encoding: str = "binary",
                         batch_size: int = 32, overwrite: bool = False) -> TeacherLabels:
    """Label the first ``states`` states of ``unlabelled_dir`` with the medoid of the teacher's ``samples`` decoded
    paths, written as a SPADE dataset at ``out_dir`` (atomically: :class:`~spade.data.writer.DatasetWriter`)."""
    if isinstance(samples, bool) or not isinstance(samples, int) or samples < 1:
        raise ValueError(f"data.unlabelled_teacher_samples={samples!r}: give a whole number >= 1 (4: the medoid "
                         "of four samples, the teacher page's reading)")
    teacher = load_module(teacher_ckpt)
    if type(teacher).__name__ != "ExpertModule":
        raise DatasetError(f"data.unlabelled_teacher={teacher_ckpt} is a student checkpoint; pass a diffusion expert's "
                           "(a conditional one: it plans for a given state)")
    if not getattr(teacher, "conditional", False):
        raise DatasetError(f"data.unlabelled_teacher={teacher_ckpt} is an unconditional expert: it draws paths for no "
                           "given state, so its samples are no label; pass a conditional (FiLM) expert")
    teacher.eval()
    source = PathDataset(unlabelled_dir, encoding=encoding)
    m = source.manifest
    n = len(source) if states is None else min(int(states), len(source))
    decode = PathMetrics(**{**dict(teacher.hparams.get("metrics") or {}), "fid": False}).decode
    arrays = source._arrays()
    h, w = source.image_size
    pixels = h * w
    start_time = time.perf_counter()
    left_out = 0
    config = {"teacher_labels": {"teacher_sha256": _sha256(Path(teacher_ckpt)), "samples": samples, "states": n,
                                 "encoding": encoding, "source": str(unlabelled_dir),
                                 "source_generator": m.generator}}
    with DatasetWriter(out_dir, (h, w), m.resolution, num_waypoints=m.num_waypoints, generator_config=config,
                       overwrite=overwrite, frame=dict(m.frame), expected_instances=n) as writer:
        for first in range(0, n, batch_size):
            index = list(range(first, min(n, first + batch_size)))
            items = [source[i] for i in index]
            batch = {"state": torch.stack([it["state"] for it in items]).float(),
                     "resolution": torch.tensor([float(it["resolution"]) for it in items])}
            maps, _ = sample_maps(teacher, batch["state"], samples)
            decoded = [[d.points if d.ok else None for d in decode(mp, batch["state"], batch["resolution"])]
                       for mp in maps]
            for j, i in enumerate(index):
                path = medoid_path([paths[j] for paths in decoded])
                if path is None:
                    left_out += 1
                    continue
                path = resample_polyline(path, m.num_waypoints)  # the dataset's waypoint count, by arc length
                occupancy = unpack_two_bit(arrays["occupancy"][i], pixels).reshape(h, w)
                start, goal = (unpack_bits(np.asarray(arrays[c][i])[None], pixels).reshape(h, w) > 0
                               for c in ("start", "goal"))
                writer.add(occupancy, start, goal, draw_polyline(path, h, w) > 0, np.asarray(path, np.float32),
                           m.label("shape", i), m.label("map_id", i), m.label("scenario_id", i),
                           np.asarray(arrays["pose"][i], np.float64))
            log.info("teacher labels: %d / %d states", min(n, first + batch_size), n)
        writer.set_extra("teacher_labels_left_out", left_out)
    return TeacherLabels(Path(out_dir), n - left_out, left_out, time.perf_counter() - start_time)


def ensure_teacher_labels(teacher_ckpt: str | Path, unlabelled_dir: str | Path, samples: int, states: int,
                          encoding: str) -> Path:
    """The teacher-labelled dataset of the first ``states`` states of ``unlabelled_dir``: read when a previous run
    wrote it (same teacher, K, states, encoding), sampled and written otherwise."""
    ckpt = Path(teacher_ckpt)
    if not ckpt.is_file():
        raise DatasetError(f"data.unlabelled_teacher={ckpt} does not exist; pass an expert checkpoint written by "
                           "python -m spade.train (e.g. spade/models/weights/cond_expert_L_gaussian_cpu_lite_x0.ckpt)")
    out = teacher_labels_dir(unlabelled_dir, ckpt, samples, states, encoding)
    if (out / "manifest.json").is_file():
        return out
    log.info("labelling %d states of %s with the teacher %s (%d samples each, once; kept at %s)", states,
             unlabelled_dir, ckpt, samples, out)
    report = write_teacher_labels(ckpt, unlabelled_dir, out, samples=samples, states=states, encoding=encoding)
    log.info("teacher labels: %d states labelled, %d left out (no sample decoded), %.0f s", report.labelled,
             report.left_out, report.seconds)
    return out


def label_unlabelled(datamodule: Any) -> Path | None:
    """Give a :class:`~spade.data.datamodule.PathDataModule` with ``unlabelled_teacher`` its teacher-labelled states
    (made once, after the unlabelled states themselves are generated); None when it names no teacher."""
    request = datamodule.teacher_label_request()
    if request is None:
        return None
    datamodule.prepare_data()  # the unlabelled states first (generated when missing)
    ckpt, source, samples, limit, encoding = request
    count = len(PathDataset(source, encoding=encoding))
    path = ensure_teacher_labels(ckpt, source, samples, min(count, limit) if limit else count, encoding)
    datamodule.use_teacher_labels(path)
    return path
