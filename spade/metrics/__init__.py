"""SPADE's evaluation metrics: APE (cm), Hd19 (artifact count) and FID, as DDP-safe torchmetrics.

Nothing is imported here, so that the numpy-only modules (:mod:`~spade.metrics.catalog`,
:mod:`~spade.metrics.shape_paths`, :mod:`~spade.metrics.extraction`, :mod:`~spade.metrics.decoding`) import without
torch; import each name from its module:

- :mod:`~spade.metrics.catalog` - every figure's name, label, unit, direction and format, in one place.
- :class:`~spade.metrics.ape.APE` - absolute pose error of the path extracted from a predicted image
  (:func:`~spade.metrics.extraction.extract_path`, the paper's) or decoded by search
  (:class:`~spade.metrics.decoding.PathDecoder`, the planner's), with the tail over 20 cm.
- :class:`~spade.metrics.hausdorff.HausdorffCount` (alias ``Hd19``) - instances whose Hausdorff distance exceeds 19
  pixels (:func:`~spade.metrics.geometry.mask_hausdorff`; the polyline APE is
  :func:`~spade.metrics.geometry.polyline_ape`).
- :class:`~spade.metrics.fid.FID` - Frechet distance of features from a pluggable, versioned extractor
  (:func:`~spade.metrics.features.build_feature_extractor`; default the shipped
  :class:`~spade.metrics.shape_features.ShapeFeatures`, trained on the project's demonstrations to see path shape;
  :class:`~spade.metrics.features.RandomConvFeatures`; :class:`~spade.metrics.features.InceptionFeatures` from a
  local torchvision weights file).
- :class:`~spade.metrics.path_metrics.PathMetrics` - the paper's and the planner's figures of predicted path
  images against a batch, as the Lightning modules log them.
"""
