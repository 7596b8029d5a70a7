"""Dataset storage (on-disk format, atomic writer, torch Dataset) and the Lightning DataModule that serves it.

Only the torch-free pieces are re-exported here (the format, the writer, polylines), so that readers and writers of
the format, the annotation tool and the planner import no torch. Import the rest from its module: the torch
``Dataset`` (:class:`~spade.data.path_dataset.PathDataset`, :func:`~spade.data.path_dataset.check_files`),
``PathDataModule`` (:mod:`spade.data.datamodule`, the target of ``conf/data/*.yaml``), the augmentation
(:mod:`spade.data.augment`), the rasterisation of an instance's images (:mod:`spade.data.rasterize`), a data
config's annotation settings (:mod:`spade.data.settings`) and the checks of its datasets against them
(:mod:`spade.data.checks`).
"""

from spade.data.format import DatasetError, Manifest, read_manifest
from spade.data.polyline import polyline_length, resample_polyline
from spade.data.writer import DatasetWriter

__all__ = [
    "DatasetError",
    "DatasetWriter",
    "Manifest",
    "polyline_length",
    "read_manifest",
    "resample_polyline",
]
