"""Interactive sketching in the browser (``python -m spade.sketch MAP.yaml``): draw a demonstration on a map,
execute it as ``spade.annotate`` does, save it to a sketch file, build the dataset, try a trained student.

- :mod:`spade.sketching.workspace`: the map, its costmap, execution, dataset builds, the planner;
- :mod:`spade.sketching.storage`: the sketch file (locked, atomic read-modify-write);
- :mod:`spade.sketching.api`: the JSON API under ``/api/``;
- :mod:`spade.sketching.app`: the FastAPI app and uvicorn; ``static/`` the page (plain JS, no build step).
"""

from spade.sketching.app import build_app, create_app, serve
from spade.sketching.workspace import RequestError, SketchWorkspace, annotation_config

__all__ = ["RequestError", "SketchWorkspace", "annotation_config", "build_app", "create_app", "serve"]
