"""Model references: a file path, or an MLflow model URI (``models:/NAME@ALIAS``, ``models:/NAME/VERSION``,
``runs:/RUN_ID/PATH``) resolved to a local ONNX file."""

from __future__ import annotations

from pathlib import Path

__all__ = ["RegistryError", "is_model_uri", "resolve_model"]

URI_SCHEMES = ("models:/", "runs:/")


class RegistryError(ValueError):
    """A model URI that cannot be resolved; the message names the registry and the fix."""


def is_model_uri(value: str) -> bool:
    return str(value).startswith(URI_SCHEMES)


def resolve_model(value: str | Path) -> Path:
    """The local model file of ``value``: a path as it is (it must exist), a model URI downloaded from MLflow."""
    text = str(value)
    if is_model_uri(text):
        raise RegistryError(f"{text}: model URIs are not supported yet; pass a model file")
    path = Path(text).expanduser()
    if not path.is_file():
        raise FileNotFoundError(f"model {path} does not exist; pass a student checkpoint (.ckpt) from python -m "
                                "spade.train, its export (.onnx / .pt) from python -m spade.export, or "
                                "models:/NAME@ALIAS")
    return path
