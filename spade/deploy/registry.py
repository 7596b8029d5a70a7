"""Students as MLflow Models: an exported ONNX student logged in MLflow's ONNX flavour (with an input/output
signature and SPADE's window metadata), registered under a name with an alias; and model references resolved to a
local file: a path, or an MLflow model URI (``models:/NAME@ALIAS``, ``models:/NAME/VERSION``, ``runs:/RUN_ID/PATH``)
downloaded from the registry (``spade.plan model=models:/spade-student@champion``, ``spade.ros`` likewise).

MLflow is imported only for URIs and registration; a deploy install that plans from files never needs it.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from spade.utils.errors import ConfigError

__all__ = ["RegisteredModel", "RegistryError", "is_model_uri", "register_onnx_student", "resolve_model"]

URI_SCHEMES = ("models:/", "runs:/")
DEFAULT_ALIAS = "champion"


class RegistryError(ConfigError):
    """A model URI that cannot be resolved, or a model that cannot be registered; the message says what to fix (a
    user error: the entry points report it as one line)."""


def is_model_uri(value: str) -> bool:
    return str(value).startswith(URI_SCHEMES)


def _mlflow(tracking_uri: str | None) -> Any:
    try:
        import mlflow
    except ImportError:
        raise RegistryError("model URIs need MLflow (pip install mlflow), or pass the model file itself") from None
    if tracking_uri:
        mlflow.set_tracking_uri(str(tracking_uri))
        mlflow.set_registry_uri(str(tracking_uri))
    return mlflow


def resolve_model(value: str | Path, tracking_uri: str | None = None, cache_dir: str | Path | None = None) -> Path:
    """The local model file of ``value``: a path as it is (it must exist); a model URI downloaded from the MLflow
    registry at ``tracking_uri`` (into ``cache_dir`` when given), its ONNX file returned."""
    text = str(value)
    if not is_model_uri(text):
        path = Path(text).expanduser()
        if not path.is_file():
            raise FileNotFoundError(f"model {path} does not exist; pass a student checkpoint (.ckpt) from python -m "
                                    "spade.train, its export (.onnx / .pt) from python -m spade.export, or "
                                    "models:/NAME@ALIAS")
        return path
    mlflow = _mlflow(tracking_uri)
    dst = None
    if cache_dir is not None:
        dst = Path(cache_dir).expanduser() / text.replace(":/", "_").replace("/", "_").replace("@", "_at_")
        dst.mkdir(parents=True, exist_ok=True)
    try:
        local = Path(mlflow.artifacts.download_artifacts(artifact_uri=text, dst_path=str(dst) if dst else None))
    except Exception as err:  # noqa: BLE001 - MLflow raises its own kinds (unknown model, alias, run, server down)
        raise RegistryError(f"{text}: cannot be fetched from the MLflow registry at {mlflow.get_tracking_uri()} "
                            f"({type(err).__name__}: {str(err).splitlines()[0] if str(err) else ''}); register the "
                            "student with python -m spade.export ... register=NAME, or pass a model file") from None
    files = [local] if local.is_file() else sorted(local.rglob("*.onnx"))
    if len(files) != 1:
        raise RegistryError(f"{text}: the model holds {len(files)} .onnx files, expected one (an MLflow ONNX model "
                            "logged by python -m spade.export register=NAME)")
    return files[0]


@dataclass(frozen=True)
class RegisteredModel:
    name: str
    version: str
    alias: str | None
    model_uri: str        # models:/NAME@ALIAS (or models:/NAME/VERSION without an alias)
    run_id: str

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def register_onnx_student(onnx_path: str | Path, name: str, alias: str | None = DEFAULT_ALIAS, *,
                          tracking_uri: str | None = None, experiment: str = "spade_models") -> RegisteredModel:
    """Log an exported ONNX student as an MLflow Model (ONNX flavour; signature: ``state`` float32 (-1, 3, H, W) ->
    ``logits`` float32 (-1, 1, H, W); the export's SPADE metadata as the model's metadata), register it as ``name``
    and point ``alias`` at the new version."""
    import numpy as np
    import onnx

    mlflow = _mlflow(tracking_uri)
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
    mlflow.set_experiment(experiment)
    with mlflow.start_run(run_name=f"register {name}") as run:
        mlflow.log_params({"source": str(path.resolve()), "image_size": f"{h}x{w}",
                           "resolution_m": info["data"]["resolution_m"]})
        logged = mlflow.onnx.log_model(model, name="model", signature=signature, registered_model_name=name,
                                       metadata={"spade": window}, save_as_external_data=False)
        run_id = run.info.run_id
    client = mlflow.MlflowClient()
    version = str(getattr(logged, "registered_model_version", None) or "")
    if not version:
        versions = client.search_model_versions(f"name='{name}' and run_id='{run_id}'")
        version = str(max(int(v.version) for v in versions))
    if alias:
        client.set_registered_model_alias(name, alias, version)
    uri = f"models:/{name}@{alias}" if alias else f"models:/{name}/{version}"
    return RegisteredModel(name, version, alias, uri, run_id)
