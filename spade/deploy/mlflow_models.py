"""Students as MLflow Models: an exported ONNX student logged in MLflow's ONNX flavour (with an input/output
signature and SPADE's window metadata), registered under a name with an alias; and model references resolved to a
local file: a path, or an MLflow model URI (``models:/NAME@ALIAS``, ``models:/NAME/VERSION``, ``runs:/RUN_ID/PATH``)
downloaded from the registry (``spade.plan model=models:/spade-student@champion``, ``spade.ros`` likewise).
:func:`log_onnx_student` logs the model into a given run without registering it: ``spade.train`` logs every student
run's best checkpoint so on its own run (``runs:/RUN_ID/model``, :mod:`spade.tracking.logged_model`).

MLflow is imported only for URIs and registration; a deploy install that plans from files never needs it.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from spade.deploy.mlflow_store import ensure_store, foreign_file_problem, mlflow_client, store_path
from spade.utils.errors import ConfigError

__all__ = ["MODEL_NAME", "RegisteredModel", "RegistryError", "is_model_uri", "log_onnx_student",
           "register_onnx_student", "resolve_model", "student_model_parts", "using_tracking_uri"]

URI_SCHEMES = ("models:/", "runs:/")
DEFAULT_ALIAS = "champion"
MODEL_NAME = "model"
"""The name a student's MLflow Model is logged under on its run: ``runs:/RUN_ID/model``."""


class RegistryError(ConfigError):
    """A model URI that cannot be resolved, or a model that cannot be registered; the message says what to fix (a
    user error: the entry points report it as one line)."""


def is_model_uri(value: str) -> bool:
    return str(value).startswith(URI_SCHEMES)


def _mlflow(tracking_uri: str | None) -> Any:
    """MLflow (the module), its tracking and registry URIs set to ``tracking_uri`` when given, a local store there
    checked, or created whole, under the store's lock first (:func:`spade.deploy.mlflow_store.ensure_store`: the
    registry's client would otherwise create a fresh store's tables while a training or an evaluation does)."""
    try:
        import mlflow
    except ImportError:
        raise RegistryError("model URIs need MLflow (pip install mlflow), or pass the model file itself") from None
    if tracking_uri:
        ensure_store(str(tracking_uri))
        mlflow.set_tracking_uri(str(tracking_uri))
        mlflow.set_registry_uri(str(tracking_uri))
    return mlflow


@contextmanager
def using_tracking_uri(tracking_uri: str | None) -> Iterator[Any]:
    """MLflow (the module) with its process-wide tracking URI set to ``tracking_uri`` inside the block and put back
    after it (the fluent API and ``log_model`` write to that URI; a Lightning logger holds its own client)."""
    mlflow = _mlflow(None)
    if not tracking_uri:
        yield mlflow
        return
    previous = mlflow.get_tracking_uri() if mlflow.is_tracking_uri_set() else None
    mlflow.set_tracking_uri(str(tracking_uri))
    try:
        yield mlflow
    finally:
        mlflow.set_tracking_uri(previous)  # None: unset again, as it was


def resolve_model(value: str | Path, tracking_uri: str | None = None, cache_dir: str | Path | None = None) -> Path:
    """The local model file of ``value``: a path as it is (it must exist); a model URI downloaded from the MLflow
    registry at ``tracking_uri`` (into ``cache_dir`` when given), its ONNX file returned. A local store that does not
    exist is refused, naming it, and never created (:func:`_check_existing_store`)."""
    text = str(value)
    if not is_model_uri(text):
        path = Path(text).expanduser()
        if not path.is_file():
            raise FileNotFoundError(f"model {path} does not exist; pass a student checkpoint (.ckpt) from python -m "
                                    "spade.train, its export (.onnx / .pt) from python -m spade.export, or "
                                    "models:/NAME@ALIAS")
        return path
    uri = str(tracking_uri) if tracking_uri else str(_mlflow(None).get_tracking_uri())
    _check_existing_store(text, uri)  # before anything is created (the store, the cache folder below)
    mlflow = _mlflow(tracking_uri)
    dst = None
    if cache_dir is not None:
        dst = Path(cache_dir).expanduser() / text.replace(":/", "_").replace("/", "_").replace("@", "_at_")
        dst.mkdir(parents=True, exist_ok=True)
    try:
        local = Path(mlflow.artifacts.download_artifacts(artifact_uri=text, dst_path=str(dst) if dst else None))
    except Exception as err:  # noqa: BLE001 - MLflow raises its own kinds (unknown model, alias, run, server down)
        reason = f"{type(err).__name__}: {str(err).splitlines()[0] if str(err) else ''}"
        if text.startswith("runs:/"):
            raise RegistryError(f"{text}: cannot be fetched from the MLflow store at {uri} ({reason}): the run is not "
                                f"in the store looked in. {OTHER_STORE}") from None
        held = registry_holdings(mlflow, text)
        if held is not None:
            raise RegistryError(f"{text}: cannot be fetched from the MLflow registry at {uri}: {held}") from None
        raise RegistryError(f"{text}: cannot be fetched from the MLflow registry at {uri} ({reason}); register the "
                            "student with python -m spade.export ... register=NAME, point MLFLOW_TRACKING_URI (or "
                            "paths.mlflow_tracking_uri) at the store it is registered in, or pass a model "
                            "file") from None
    files = [local] if local.is_file() else sorted(local.rglob("*.onnx"))
    if len(files) != 1:
        raise RegistryError(f"{text}: the model holds {len(files)} .onnx files, expected one (an MLflow ONNX model "
                            "logged by python -m spade.export register=NAME)")
    return files[0]


def registry_holdings(mlflow: Any, text: str) -> str | None:
    """What the registry holds under the name of ``text`` (``models:/NAME/VERSION`` or ``models:/NAME@ALIAS``), as
    the refusal's cause and fix: the versions and aliases that exist (``models:/NAME/99`` named none of them), or
    that no model is registered under NAME with the names that are. None when it cannot tell (another kind of
    URI, or the registry does not answer)."""
    if not text.startswith("models:/"):
        return None
    rest = text[len("models:/"):]
    name, sep, alias = rest.partition("@")
    if not sep:
        name = rest.rsplit("/", 1)[0] if "/" in rest else rest
    try:
        client = mlflow_client(mlflow.get_tracking_uri())
        versions = sorted(int(v.version) for v in client.search_model_versions(f"name='{name}'"))
        if not versions:
            names = sorted(m.name for m in client.search_registered_models())
            return (f"no model is registered as {name!r} (registered: {names or 'none'}); give one of those names, "
                    "or register the student with python -m spade.export ... register=NAME")
        aliases = dict(getattr(client.get_registered_model(name), "aliases", None) or {})
    except Exception:  # noqa: BLE001 - the registry did not answer: the caller's generic refusal
        return None
    held = f"{name} has versions {versions}" + (f" and aliases {aliases}" if aliases else " and no aliases")
    example = f"models:/{name}/{versions[-1]}" + (f" or models:/{name}@{next(iter(aliases))}" if aliases else "")
    return f"{held}; give one of them, e.g. {example}"


OTHER_STORE = ("Point MLFLOW_TRACKING_URI (or paths.mlflow_tracking_uri=..., or SPADE_HOME) at the store the run was "
               "logged to, e.g. MLFLOW_TRACKING_URI=sqlite:////path/to/logs/mlflow.db, or pass the run's checkpoint "
               "(model=.../checkpoints/epochNNN.ckpt, printed at the end of its training)")
"""How to look a model URI up elsewhere: what the refusals below end with."""


def _check_existing_store(text: str, uri: str) -> None:
    """A model URI is looked up in an existing MLflow store, never a new one: MLflow opens a missing SQLite store by
    creating it (its folder, file and tables), so ``spade.plan model=runs:/...`` run from another folder than the
    run's left an empty ``logs/mlflow.db`` there and answered that the run was not found. A server answers for
    itself; an SQLite file that is no MLflow store is refused unopened
    (:func:`spade.deploy.mlflow_store.foreign_file_problem`)."""
    path = store_path(uri)
    if path is None:
        return
    if not path.exists():
        raise RegistryError(f"{text}: no MLflow store at {uri} (looked for {path}; none was created). {OTHER_STORE}")
    foreign = foreign_file_problem(path)
    if foreign:
        raise RegistryError(f"{text}: {foreign}. {OTHER_STORE}")


@dataclass(frozen=True)
class RegisteredModel:
    name: str
    version: str
    alias: str | None
    model_uri: str        # models:/NAME@ALIAS (or models:/NAME/VERSION without an alias)
    run_id: str

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def student_model_parts(onnx_path: str | Path) -> tuple[Any, Any, dict[str, Any]]:
    """(the ONNX model, its MLflow signature, its window metadata) of an export of ``python -m spade.export``: the
    signature ``state`` float32 (-1, 3, H, W) -> ``logits`` float32 (-1, 1, H, W), the metadata the window a
    planner builds (size, metres per pixel, robot frame, input encoding) and the role."""
    import numpy as np
    import onnx
    from mlflow.models.signature import ModelSignature
    from mlflow.types.schema import Schema, TensorSpec

    path = Path(onnx_path)
    model = onnx.load(str(path))
    props = {p.key: p.value for p in model.metadata_props}
    if "spade" not in props:
        raise RegistryError(f"{path} carries no SPADE metadata: register an export of python -m spade.export")
    info = json.loads(props["spade"])
    h, w = (int(v) for v in info["data"]["image_size"])
    signature = ModelSignature(inputs=Schema([TensorSpec(np.dtype(np.float32), (-1, 3, h, w), "state")]),
                               outputs=Schema([TensorSpec(np.dtype(np.float32), (-1, 1, h, w), "logits")]))
    window = {"image_size": [h, w], "resolution_m": info["data"]["resolution_m"], "frame": info["data"]["frame"],
              "input_encoding": info["data"].get("input_encoding"), "role": info.get("role")}
    return model, signature, window


def log_onnx_student(onnx_path: str | Path, run_id: str, *, name: str = MODEL_NAME,
                     registered_model_name: str | None = None) -> Any:
    """Log an exported ONNX student as an MLflow Model on run ``run_id`` of MLflow's current store: ONNX flavour, the signature and window metadata of :func:`student_model_parts`, the flavour's
    own pip requirements (onnx, onnxruntime: MLflow's inference of them would load the model in a subprocess,
    seconds), registered as ``registered_model_name`` when given. The run lists it in its Models column; it loads
    as ``runs:/RUN_ID/NAME`` or the returned ``ModelInfo.model_uri`` (``models:/m-...``).

    The run may have finished already (``spade.train`` logs its student after the test ended the run): the
    logged model is created in the run's own experiment, whatever experiment is active in this process."""
    mlflow = _mlflow(None)
    model, signature, window = student_model_parts(onnx_path)
    client = mlflow_client()
    run = client.get_run(run_id)
    # Created here, in the run's experiment: left to MLflow, a model logged into a run that is not the active one
    # would go to the active experiment (mlflow.set_experiment, MLFLOW_EXPERIMENT_NAME) when one is set.
    logged = client.create_logged_model(run.info.experiment_id, name=name, source_run_id=run_id,
                                        params={k: str(v) for k, v in run.data.params.items()})
    return mlflow.onnx.log_model(model, name=name, model_id=logged.model_id, run_id=run_id, signature=signature,
                                 registered_model_name=registered_model_name, metadata={"spade": window},
                                 save_as_external_data=False,
                                 pip_requirements=mlflow.onnx.get_default_pip_requirements())


def register_onnx_student(onnx_path: str | Path, name: str, alias: str | None = DEFAULT_ALIAS, *,
                          tracking_uri: str | None = None, experiment: str = "spade_models") -> RegisteredModel:
    """Log an exported ONNX student as an MLflow Model (:func:`log_onnx_student`) in a run of its own in
    ``experiment``, register it as ``name`` and point ``alias`` at the new version."""
    mlflow = _mlflow(tracking_uri)
    path = Path(onnx_path)
    _, _, window = student_model_parts(path)  # refuses a file without SPADE metadata before any run is made
    h, w = window["image_size"]
    mlflow.set_experiment(experiment)
    with mlflow.start_run(run_name=f"register {name}") as run:
        mlflow.log_params({"source": str(path.resolve()), "image_size": f"{h}x{w}",
                           "resolution_m": window["resolution_m"]})
        logged = log_onnx_student(path, run.info.run_id, registered_model_name=name)
        run_id = run.info.run_id
    client = mlflow_client()
    version = str(getattr(logged, "registered_model_version", None) or "")
    if not version:
        versions = client.search_model_versions(f"name='{name}' and run_id='{run_id}'")
        version = str(max(int(v.version) for v in versions))
    if alias:
        client.set_registered_model_alias(name, alias, version)
    uri = f"models:/{name}@{alias}" if alias else f"models:/{name}/{version}"
    return RegisteredModel(name, version, alias, uri, run_id)
