"""Dataset storage: the on-disk format, its atomic writer and the torch Dataset that reads it."""

from spade.data.dataset import PathDataset, check_files
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
