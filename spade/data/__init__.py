"""Dataset storage (on-disk format, atomic writer, torch Dataset) and the Lightning DataModule that serves it.

``PathDataModule`` (:mod:`spade.data.datamodule`, the target of ``conf/data/*.yaml``) and the augmentation
(:mod:`spade.data.augment`) are not imported here, so that readers of the format do not pull in Lightning; nor
are the rasterisation of an instance's images (:mod:`spade.data.rasterize`), a data config's annotation settings
(:mod:`spade.data.settings`) and the checks of its datasets against them (:mod:`spade.data.checks`).
"""

from spade.data.path_dataset import PathDataset, check_files
from spade.data.format import DatasetError, Manifest, read_manifest
from spade.data.polyline import polyline_length, resample_polyline
from spade.data.writer import DatasetWriter

__all__ = [
    "DatasetError",
    "DatasetWriter",
    "Manifest",
    "PathDataset",
    "check_files",
    "polyline_length",
    "read_manifest",
    "resample_polyline",
]
