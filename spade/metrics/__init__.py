"""SPADE's evaluation metrics: APE (cm), Hd19 (artifact count) and FID, as DDP-safe torchmetrics.

- :mod:`~spade.metrics.catalog` - every figure's name, label, unit, direction and format, in one place.

- :class:`APE` - absolute pose error of the path extracted from a predicted image (:func:`extract_path`, the
  paper's) or decoded by search (:class:`PathDecoder`, the planner's), with the tail over 20 cm.
- :class:`HausdorffCount` (alias :data:`Hd19`) - instances whose Hausdorff distance exceeds 19 pixels.
- :class:`FID` - Frechet distance of features from a pluggable, versioned extractor (default the shipped
  :class:`ShapeFeatures`, trained on the project's demonstrations to see path shape; :class:`RandomConvFeatures`;
  :class:`InceptionFeatures` from a local torchvision weights file).
- :class:`~spade.metrics.path_metrics.PathMetrics` - the paper's and the planner's figures of predicted path
  images against a batch, as the Lightning modules log them (import it from :mod:`spade.metrics.path_metrics`).
"""

from __future__ import annotations

from spade.utils.lazy_exports import lazy_exports

_HOMES = {
    "APE": "ape",
    "DecodedPath": "decoding",
    "FID": "fid",
    "ExtractedPath": "extraction",
    "HausdorffCount": "hausdorff",
    "Hd19": "hausdorff",
    "InceptionFeatures": "features",
    "PathDecoder": "decoding",
    "RandomConvFeatures": "features",
    "ShapeFeatures": "shape_features",
    "build_feature_extractor": "features",
    "decode_path": "decoding",
    "extract_path": "extraction",
    "frechet_distance": "fid",
    "mask_hausdorff": "geometry",
    "marker_centre": "extraction",
    "polyline_ape": "geometry",
}
"""Where each name lives: imported on first use, so that ``spade.metrics.catalog`` or ``shape_paths`` (numpy only)
can be imported without torch."""

__all__ = sorted(_HOMES)


__getattr__ = lazy_exports(__name__, _HOMES, globals())
