"""The JSON API under ``/api/`` that the page uses and scripts can call (README: *Sketching in the browser*).

Every refused request answers ``{"error": "<what is wrong and what to send instead>"}`` with a 4xx status:
400 malformed JSON, 404 unknown sketch or model file, 409 a conflict (name taken, build running, no model,
nothing saved), 422 a well-formed request the app cannot accept (unknown shape, points outside the map,
a model that is not a student, a sketch the execution rejects on save).
"""

from __future__ import annotations

from typing import Any, Optional

from fastapi import APIRouter, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, Response
from pydantic import BaseModel, ConfigDict, Field

from spade.sketching.workspace import RequestError, SketchWorkspace


class _Body(BaseModel):
    model_config = ConfigDict(extra="forbid")


MAX_WAYPOINTS = 2000  # a drawn sketch has tens to a few hundred points; more is refused (422)


class SketchBody(_Body):
    shape: str = Field(description="shape label: L or U")
    waypoints: list[list[float]] = Field(max_length=MAX_WAYPOINTS,
                                         description="[[x, y], ...] map-frame metres, in driving order, goal last "
                                                     f"(at most {MAX_WAYPOINTS})")


class SaveBody(SketchBody):
    name: Optional[str] = Field(default=None, description="unique name; default {shape}{k:03d}")


class BuildBody(_Body):
    wait: bool = Field(default=False, description="answer only when the build has finished")


class ModelBody(_Body):
    path: str = Field(description="a student checkpoint (.ckpt) or ONNX export (.onnx) on the server")


class PlanBody(_Body):
    pose: list[float] = Field(description="robot pose [x, y, yaw]: metres, radians counter-clockwise from +x")
    goal: list[float] = Field(description="goal [x, y] in metres")


def _png(data: bytes) -> Response:
    return Response(content=data, media_type="image/png", headers={"Cache-Control": "no-store"})


def router(ws: SketchWorkspace) -> APIRouter:
    """The API's routes on one workspace."""
    api = APIRouter(prefix="/api")

    @api.get("/map")
    def map_metadata() -> dict[str, Any]:
        """Map metadata: size in cells and metres, resolution, origin, shapes, robot, window, files, model."""
        return ws.metadata()

    @api.get("/map.png")
    def map_png() -> Response:
        """The map, one pixel per cell (row 0 is the top, +y of the map frame)."""
        return _png(ws.map_png())

    @api.get("/costmap.png")
    def costmap_png() -> Response:
        """The inflated costmap overlay (transparent PNG, same size as the map)."""
        return _png(ws.costmap_png())

    @api.post("/execute")
    def execute(body: SketchBody) -> dict[str, Any]:
        """Execute a sketch as spade.annotate does; 200 whether it is accepted or rejected (then with the reason)."""
        return ws.execute(body.shape, body.waypoints)

    @api.get("/sketches")
    def list_sketches() -> dict[str, Any]:
        """The saved sketches, in file order."""
        return ws.sketches()

    @api.post("/sketches", status_code=201)
    def save(body: SaveBody) -> dict[str, Any]:
        """Execute and append an accepted sketch to the sketch file (atomic)."""
        return ws.save(body.shape, body.waypoints, body.name)

    @api.get("/sketches/{name}")
    def get_sketch(name: str) -> dict[str, Any]:
        try:
            return ws.store.get(name)
        except ValueError as exc:
            raise RequestError(str(exc), getattr(exc, "status", 404)) from None

    @api.delete("/sketches/{name}")
    def delete(name: str) -> dict[str, Any]:
        """Remove a saved sketch (atomic)."""
        return ws.delete(name)

    @api.post("/build", status_code=202)
    def build(body: Optional[BuildBody] = None) -> dict[str, Any]:
        """Build the dataset from the sketch file with spade.annotate; poll GET /api/build for progress."""
        return ws.start_build(wait=bool(body and body.wait))

    @api.get("/build")
    def build_status() -> dict[str, Any]:
        return ws.build.to_json()

    @api.get("/build/preview.png")
    def build_preview() -> Response:
        """The contact sheet of the last built dataset."""
        path = ws.dataset_dir / "preview.png"
        if not path.is_file():
            raise RequestError("no dataset preview yet: build the dataset first (POST /api/build)", status=404)
        return _png(path.read_bytes())

    @api.get("/model")
    def model() -> dict[str, Any]:
        return {"model": ws.model_info()}

    @api.post("/model")
    def load_model(body: ModelBody) -> dict[str, Any]:
        """Load a student for "Try the policy"; an expert or a file that is no model is refused (422)."""
        return {"model": ws.load_model(body.path)}

    @api.post("/plan")
    def plan(body: PlanBody) -> dict[str, Any]:
        """The student's plan from a robot pose to a goal: waypoints in metres, probability image, latency."""
        return ws.plan(body.pose, body.goal)

    return api


def _short(value: Any, limit: int = 80) -> str:
    """``repr(value)`` cut to ``limit`` characters: an error never echoes a whole oversized request."""
    if isinstance(value, (list, tuple)) and len(value) > 8:
        return f"a list of {len(value):,} items"
    text = repr(value)
    return text if len(text) <= limit else text[:limit - 3] + "..."


def _where(loc: tuple[Any, ...]) -> str:
    parts = [str(p) for p in loc if p != "body"]
    return ".".join(parts) or "body"


async def validation_error(request: Request, exc: RequestValidationError) -> JSONResponse:
    """FastAPI's validation errors as one readable message (400 for malformed JSON, else 422)."""
    errors = exc.errors()
    if any(e.get("type") == "json_invalid" for e in errors):
        detail = next(e for e in errors if e.get("type") == "json_invalid").get("ctx", {}).get("error", "")
        return JSONResponse({"error": f"malformed JSON in the request body ({detail}); send a JSON object such "
                                      f"as {{\"shape\": \"L\", \"waypoints\": [[1.0, 2.0], [3.0, 2.0]]}}"},
                            status_code=400)
    lines = []
    for e in errors:
        where = _where(tuple(e.get("loc", ())))
        if e.get("type") == "missing":
            lines.append(f"{where}: missing")
        elif e.get("type") == "extra_forbidden":
            lines.append(f"{where}: unknown field")
        else:
            lines.append(f"{where}: {e.get('msg')} (got {_short(e.get('input'))})")
    return JSONResponse({"error": "invalid request: " + "; ".join(lines), "details": errors and [
        {"loc": list(e.get("loc", ())), "msg": e.get("msg"), "type": e.get("type")} for e in errors]},
                        status_code=422)


async def request_error(request: Request, exc: Exception) -> JSONResponse:
    """A refused request (:class:`RequestError`) or a sketch file the store refuses
    (:class:`~spade.sketching.storage.StorageError`): ``{"error": ...}`` with its 4xx status."""
    return JSONResponse({"error": str(exc)}, status_code=int(getattr(exc, "status", 400)))
