"""SPADE's evaluation metrics: APE (cm), Hd19 (artifact count) and FID, as DDP-safe torchmetrics.

- :class:`APE` - absolute pose error of the path extracted from a predicted image (:func:`extract_path`).
- :class:`HausdorffCount` (alias :data:`Hd19`) - instances whose Hausdorff distance exceeds 19 pixels.
- :class:`FID` - Frechet distance of features from a pluggable, versioned extractor (default offline
  :class:`RandomConvFeatures`; :class:`InceptionFeatures` from a local torchvision weights file).
"""

from spade.metrics.ape import APE
from spade.metrics.extraction import ExtractedPath, extract_path, marker_centre
from spade.metrics.features import InceptionFeatures, RandomConvFeatures, build_feature_extractor
from spade.metrics.fid import FID, frechet_distance
from spade.metrics.geometry import mask_hausdorff, polyline_ape
from spade.metrics.hausdorff import HausdorffCount, Hd19

__all__ = [
    "APE",
    "FID",
    "ExtractedPath",
    "HausdorffCount",
    "Hd19",
    "InceptionFeatures",
    "RandomConvFeatures",
    "build_feature_extractor",
    "extract_path",
    "frechet_distance",
    "mask_hausdorff",
    "marker_centre",
    "polyline_ape",
]
