"""SPADE's evaluation metrics: APE (cm), Hd19 (artifact count) and FID, as DDP-safe torchmetrics.

- :class:`APE` - absolute pose error of the path extracted from a predicted image (:func:`extract_path`, the
  paper's) or decoded by search (:class:`PathDecoder`, the planner's), with the tail over 20 cm.
- :class:`HausdorffCount` (alias :data:`Hd19`) - instances whose Hausdorff distance exceeds 19 pixels.
- :class:`FID` - Frechet distance of features from a pluggable, versioned extractor (default the shipped
  :class:`ShapeFeatures`, trained on the project's demonstrations to see path shape; :class:`RandomConvFeatures`;
  :class:`InceptionFeatures` from a local torchvision weights file).
- :class:`~spade.metrics.path_metrics.PathMetrics` - the paper's and the planner's figures of predicted path
  images against a batch, as the Lightning modules log them (import it from :mod:`spade.metrics.path_metrics`).
"""

from spade.metrics.ape import APE
from spade.metrics.decoding import DecodedPath, PathDecoder, decode_path
from spade.metrics.extraction import ExtractedPath, extract_path, marker_centre
from spade.metrics.features import InceptionFeatures, RandomConvFeatures, build_feature_extractor
from spade.metrics.shape_features import ShapeFeatures
from spade.metrics.fid import FID, frechet_distance
from spade.metrics.geometry import mask_hausdorff, polyline_ape
from spade.metrics.hausdorff import HausdorffCount, Hd19

__all__ = [
    "APE",
    "DecodedPath",
    "FID",
    "ExtractedPath",
    "HausdorffCount",
    "Hd19",
    "InceptionFeatures",
    "PathDecoder",
    "RandomConvFeatures",
    "ShapeFeatures",
    "build_feature_extractor",
    "decode_path",
    "extract_path",
    "frechet_distance",
    "mask_hausdorff",
    "marker_centre",
    "polyline_ape",
]
