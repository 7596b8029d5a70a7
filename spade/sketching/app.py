"""The FastAPI app: the JSON API (:mod:`spade.sketching.api`) and one static page (``static/``), nothing loaded
from anywhere else (no CDN: robots and CI have no internet).

The app obeys only its user (as MLflow 3's and Jupyter's local servers do): a request whose ``Host`` header is not
one of the app's own names (127.0.0.1, localhost, ::1 and the address it is bound to) is refused, which stops a web
page from reaching it by DNS rebinding; a state-changing request (anything but GET / HEAD / OPTIONS) from another
origin (``Origin`` or ``Sec-Fetch-Site``) is refused, which stops cross-site form posts; both answer 403 with
``{"error": ...}``. Model files are loaded only from the workspace's model folders
(:class:`~spade.sketching.workspace.SketchWorkspace`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Sequence

from urllib.parse import urlsplit

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse
from fastapi.staticfiles import StaticFiles

from spade.sketching.api import request_error, router, validation_error
from spade.sketching.storage import StorageError
from spade.sketching.workspace import RequestError, SketchWorkspace, annotation_config

STATIC_DIR = Path(__file__).resolve().parent / "static"


LOCAL_HOSTS = ("127.0.0.1", "localhost", "::1")
SAFE_METHODS = ("GET", "HEAD", "OPTIONS")
# The largest request body the API reads: a sketch of MAX_WAYPOINTS points is about 40 kB of JSON, so 1 MiB is
# generous; a larger body is refused (413) from its Content-Length before a byte of it is read.
MAX_BODY_BYTES = 1 << 20


def allowed_hosts(hosts: Sequence[str] = ()) -> frozenset[str]:
    """The host names the app answers to: the loopback names and ``hosts`` (the bound address, ``allowed_hosts``);
    bound to every interface (0.0.0.0, ::), also this machine's name."""
    import socket

    names = {*LOCAL_HOSTS}
    for host in hosts:
        host = str(host).strip().strip("[]").lower()
        if host in ("0.0.0.0", "::", ""):
            names.add(socket.gethostname().lower())
        else:
            names.add(host)
    return frozenset(names)


def _host_name(netloc: str) -> str | None:
    try:
        return urlsplit(f"//{netloc}").hostname  # lower case, brackets and port removed
    except ValueError:
        return None


def _refused(message: str) -> JSONResponse:
    return JSONResponse({"error": message}, status_code=403)


def _body_refusal(request: Request) -> JSONResponse | None:
    """413 for a body over :data:`MAX_BODY_BYTES`, 411 for a body sent without a length (chunked), else None."""
    length = request.headers.get("content-length")
    if length is None:
        if request.headers.get("transfer-encoding"):
            return JSONResponse({"error": "a request body needs a Content-Length header (chunked bodies are not "
                                          "read); send the JSON with its length"}, status_code=411)
        return None
    try:
        size = int(length)
    except ValueError:
        return JSONResponse({"error": f"Content-Length {length!r} is not a number"}, status_code=400)
    if size > MAX_BODY_BYTES:
        return JSONResponse({"error": f"request body of {size:,} bytes refused: the API reads at most "
                                      f"{MAX_BODY_BYTES:,} bytes (a sketch is a few kB); send fewer waypoints"},
                            status_code=413)
    return None


def create_app(workspace: SketchWorkspace, hosts: Sequence[str] = ()) -> FastAPI:
    """The app around one workspace (map, sketch file, dataset, planner); ``hosts``: host names it answers to
    besides 127.0.0.1, localhost and ::1 (the address it is bound to)."""
    app = FastAPI(title="SPADE sketching", summary="Draw demonstrations on a map, execute, save, build, plan",
                  docs_url=None, redoc_url=None, openapi_url="/api/openapi.json")  # Swagger UI would need a CDN
    app.state.workspace = workspace
    app.state.allowed_hosts = names = allowed_hosts(hosts)

    @app.middleware("http")
    async def only_its_user(request: Request, call_next: Any) -> Any:
        host = request.headers.get("host", "")
        if _host_name(host) not in names:
            return _refused(f"Host {host!r} is not this server (it answers to {', '.join(sorted(names))}); open it "
                            "as http://127.0.0.1:PORT/, or start it with allowed_hosts=[NAME]")
        if request.method not in SAFE_METHODS:
            origin = request.headers.get("origin")
            if origin is not None:
                parts = urlsplit(origin) if origin != "null" else None
                if parts is None or parts.netloc.lower() != host.lower() or parts.scheme not in ("http", "https"):
                    return _refused(f"cross-origin {request.method} refused: Origin {origin!r} is not this server's "
                                    f"page (http://{host}); use the page it serves, or a script without an Origin")
            site = request.headers.get("sec-fetch-site")
            if site is not None and site not in ("same-origin", "none"):
                return _refused(f"cross-site {request.method} refused (Sec-Fetch-Site: {site}); use the page this "
                                "server serves")
            if (refusal := _body_refusal(request)) is not None:
                return refusal
        return await call_next(request)
    app.add_exception_handler(RequestValidationError, validation_error)  # type: ignore[arg-type]
    app.add_exception_handler(RequestError, request_error)  # type: ignore[arg-type]
    app.add_exception_handler(StorageError, request_error)  # type: ignore[arg-type]  # the file's state: 4xx
    app.include_router(router(workspace))
    app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")

    @app.get("/", include_in_schema=False)
    def index() -> FileResponse:
        return FileResponse(STATIC_DIR / "index.html", headers={"Cache-Control": "no-store"})

    return app


def build_app(map_spec: str, out_dir: str | Path, annotate: Sequence[str] | Mapping[str, Any] = (),
              model: str | Path | None = None, device: str = "cpu", hosts: Sequence[str] = (),
              models: Sequence[str | Path] | None = None, allow_unsigned: bool = False) -> FastAPI:
    """Workspace and app in one call. ``annotate``: overrides of conf/annotate.yaml, as ``key=value`` strings
    (``["window.size_px=64"]``) or a nested mapping (``{"window": {"size_px": 64}}``); ``hosts``: host names
    the app answers to besides the loopback ones; ``models``: the folders ``POST /api/model`` may load from
    (default: the working directory, the map's folder, ``out_dir`` and ``model``'s folder); ``allow_unsigned``: open
    model exports that carry no integrity record (the Planner's opt-in), at start-up and through ``POST /api/model``."""
    overrides = flatten_overrides(annotate) if isinstance(annotate, Mapping) else list(annotate)
    workspace = SketchWorkspace(map_spec, out_dir, annotation_config(overrides), model, device, overrides,
                                model_dirs=models, allow_unsigned=allow_unsigned)
    return create_app(workspace, hosts)


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


def serve(app: FastAPI, host: str = "127.0.0.1", port: int = 8770) -> None:
    """Run the app with uvicorn until interrupted."""
    import uvicorn

    ws: SketchWorkspace = app.state.workspace
    print(f"SPADE sketching on http://{host}:{port}/  map {ws.map_ref} ({ws.map.width} x {ws.map.height} cells at "
          f"{ws.map.resolution} m)\n  sketch file {ws.store.path} ({len(ws.store.list())} saved)\n  dataset "
          f"{ws.dataset_dir}\n  model {ws.model_path or '-'}", flush=True)
    uvicorn.run(app, host=host, port=port, log_level="warning")
