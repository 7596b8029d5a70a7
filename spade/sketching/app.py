"""The FastAPI app: the JSON API (:mod:`spade.sketching.api`) and one static page (``static/``), nothing loaded
from anywhere else (no CDN: robots and CI have no internet)."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Sequence

from fastapi import FastAPI
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse
from fastapi.staticfiles import StaticFiles

from spade.sketching.api import request_error, router, validation_error
from spade.sketching.workspace import RequestError, SketchWorkspace, annotation_config

STATIC_DIR = Path(__file__).resolve().parent / "static"


def create_app(workspace: SketchWorkspace) -> FastAPI:
    """The app around one workspace (map, sketch file, dataset, planner)."""
    app = FastAPI(title="SPADE sketching", summary="Draw demonstrations on a map, execute, save, build, plan",
                  docs_url=None, redoc_url=None, openapi_url="/api/openapi.json")  # Swagger UI would need a CDN
    app.state.workspace = workspace
    app.add_exception_handler(RequestValidationError, validation_error)  # type: ignore[arg-type]
    app.add_exception_handler(RequestError, request_error)  # type: ignore[arg-type]
    app.include_router(router(workspace))
    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")

    @app.get("/", include_in_schema=False)
    def index() -> FileResponse:
        return FileResponse(STATIC_DIR / "index.html", headers={"Cache-Control": "no-store"})

    return app


def build_app(map_spec: str, out_dir: str | Path, annotate: Sequence[str] | Mapping[str, Any] = (),
              model: str | Path | None = None, device: str = "cpu") -> FastAPI:
    """Workspace and app in one call. ``annotate``: overrides of conf/annotate.yaml, as ``key=value`` strings
    (``["window.size_px=64"]``) or a nested mapping (``{"window": {"size_px": 64}}``)."""
    overrides = flatten_overrides(annotate) if isinstance(annotate, Mapping) else list(annotate)
    return create_app(SketchWorkspace(map_spec, out_dir, annotation_config(overrides), model, device, overrides))


def flatten_overrides(tree: Mapping[str, Any], prefix: str = "") -> list[str]:
    """``{"window": {"size_px": 64}}`` -> ``["window.size_px=64"]`` (Hydra override syntax, values quoted)."""
    import json

    out: list[str] = []
    for key, value in tree.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping) and value:
            out.extend(flatten_overrides(value, name + "."))
        else:
            out.append(f"preset={value}" if name == "preset" else f"{name}={json.dumps(value)}")
    return out


def serve(app: FastAPI, host: str = "127.0.0.1", port: int = 8765) -> None:
    """Run the app with uvicorn until interrupted."""
    import uvicorn

    ws: SketchWorkspace = app.state.workspace
    print(f"SPADE sketching on http://{host}:{port}/  map {ws.map_ref} ({ws.map.width} x {ws.map.height} cells at "
          f"{ws.map.resolution} m)\n  sketch file {ws.store.path} ({len(ws.store.list())} saved)\n  dataset "
          f"{ws.dataset_dir}\n  model {ws.model_path or '-'}", flush=True)
    uvicorn.run(app, host=host, port=port, log_level="warning")
