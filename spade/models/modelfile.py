"""The model file: one owner for what SPADE writes into, and reads from, checkpoints and exported students.

A **checkpoint** written by ``python -m spade.train`` carries, next to Lightning's entries, the ``spade`` entry

    {"role": "student" | "expert", "config": <net.config>,
     "data": {"image_size": [H, W], "resolution_m": ..., "frame": {"kind": "robot", "size_px": S,
              "robot_px": [x, y], "heading": "up"}, "input_encoding": INPUT_ENCODING,
              "disc_radius_m": ..., "margin_m": ...,
              "footprint": {"radius_m": ..., "inflation_radius_m": ...}},
     "mlflow_run_id": ...}

(:func:`checkpoint_entry`, called by ``PathPlanningModule.on_save_checkpoint``). ``data`` describes the windows
the network was trained on (``footprint``: the robot radius and inflation its demonstrations assumed, from the
annotation's ``robot`` block); ``frame`` is the robot frame of :mod:`spade.maps.frame` (absent in models
trained on the older, axis-aligned windows). An **export** (ONNX ``metadata_props["spade"]``, TorchScript extra
file ``spade.json``) carries the same entry as JSON plus the export's own fields (:func:`export_metadata`).

Reading is safe: checkpoints are opened with ``torch.load(..., weights_only=True)``, which unpickles only
tensors, plain Python data and the types in :data:`SAFE_GLOBALS`; a file whose pickle names anything else (a
checkpoint that would run code when loaded) is refused with :class:`UnsafeModelFileError`, before any of it
runs. :func:`load_lightning` applies the same rule to Lightning's ``load_from_checkpoint``, and
:func:`safe_loading` to loads made inside other code (``Trainer.fit`` / ``Trainer.test`` with a ``ckpt_path``).

:func:`open_model` opens any of the three kinds of file (checkpoint, ONNX, TorchScript) as one callable,
``ModelRunner(states) -> logits``, with one device policy (:func:`resolve_device`). An export (ONNX or TorchScript)
must be the one its metadata describes (shapes, weight digest, parity probe, the digests of the fields a planner
acts on: :mod:`spade.models.onnx_check`); one without that record is refused unless ``allow_unsigned``.

This module sits on the models floor: it imports torch, numpy, :mod:`spade.models.builders` and
:mod:`spade.models.onnx_session` (the ONNX Runtime set-up both ONNX runners share) only (onnx, onnxruntime and
Lightning lazily, where a function needs them), so that training, evaluation, export, the
planner and the benchmarks can all import it.
"""

from __future__ import annotations

import collections
import contextlib
import json
import pathlib
import pickle
import re
import typing
import warnings
import zipfile
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from spade.models.onnx_session import OUTPUT_NAME, OnnxSession
from spade.utils.devices import device_name
from spade.utils.errors import UserError
from spade.maps.frame import RobotFrame
from spade.models.builders import build_model, model_from_config
from spade.models.onnx_check import archive_sha256, check_student_export, weights_sha256

__all__ = [
    "INPUT_ENCODING", "SAFE_GLOBALS", "ModelFileError", "ModelRunner", "UnsafeModelFileError", "build_network",
    "checkpoint_entry", "export_metadata", "file_format", "load_checkpoint", "load_lightning", "load_network",
    "open_model", "plain", "read_info", "read_metadata", "require_role", "resolve_device", "robot_frame",
    "safe_loading", "untrained_student",
]

INPUT_ENCODING = "occupancy code * 0.5 (unknown 0, free 0.5, occupied 1), start, goal"
"""The network input, as every model file records it (``PathDataset`` builds it); how the start and goal
are drawn is ``data.marker_encoding`` (:mod:`spade.data.encoding`; ``binary`` where a model file predates it)."""
DEFAULT_FOOTPRINT = {"radius_m": 0.105, "inflation_radius_m": 0.55}
"""conf/annotate.yaml's ``robot`` (a TurtleBot3 Burger with Nav2's default inflation): what a model file that
predates footprint records was trained for, unless its user changed the annotation config."""
ENTRY_KEY = "spade"  # the checkpoint entry, and the ONNX metadata_props key
TORCHSCRIPT_METADATA_FILE = "spade.json"
INPUT_NAME = "state"
FORMATS = ("checkpoint", "onnx", "torchscript")
RUNTIMES = {"checkpoint": "pytorch", "onnx": "onnxruntime", "torchscript": "torchscript"}
RETRAIN = ("retrain it on robot-frame windows (python -m spade.train +experiment=<row>, which rebuilds old "
           "datasets) and export it again")


def _safe_globals() -> list[Any]:
    """What a SPADE or Lightning checkpoint may hold besides tensors and plain data.

    Lightning stores the module's hyper-parameters (plain data: the model configs are instantiated with
    ``_convert_: all``, and :func:`checkpoint_entry`'s caller converts any OmegaConf container it still finds),
    loop and callback states (dicts, tensors, strings). Checkpoints written before that conversion, or by code
    that passes OmegaConf containers, hold DictConfig/ListConfig and their nodes; paths may appear as
    ``pathlib`` objects. All of these only rebuild data; functions, optimiser factories (``functools.partial``)
    and arbitrary classes stay refused.
    """
    out: list[Any] = [dict, list, int, collections.OrderedDict, collections.defaultdict, typing.Any,
                      pathlib.PosixPath, pathlib.PurePosixPath, pathlib.WindowsPath, pathlib.PureWindowsPath]
    try:
        from omegaconf import DictConfig, ListConfig
        from omegaconf.base import ContainerMetadata, Metadata
        from omegaconf.nodes import AnyNode, BooleanNode, BytesNode, FloatNode, IntegerNode, PathNode, StringNode

        out += [DictConfig, ListConfig, ContainerMetadata, Metadata, AnyNode, BooleanNode, BytesNode, FloatNode,
                IntegerNode, PathNode, StringNode]
    except ImportError:  # pragma: no cover - omegaconf comes with Hydra, a dependency
        pass
    return out


SAFE_GLOBALS: list[Any] = _safe_globals()


class ModelFileError(UserError, ValueError):
    """A model file SPADE cannot use as it is; the message names the file and the fix."""


class UnsafeModelFileError(ModelFileError):
    """A checkpoint whose pickle names a Python object beyond tensors, plain data and :data:`SAFE_GLOBALS`."""


# -- writing ---------------------------------------------------------------------------------------------------
def plain(value: Any) -> Any:
    """``value`` with every OmegaConf container turned into dicts and lists (what a checkpoint may hold)."""
    try:
        from omegaconf import OmegaConf
    except ImportError:  # pragma: no cover
        return value
    if OmegaConf.is_config(value):
        return OmegaConf.to_container(value, resolve=True)
    if isinstance(value, dict):
        return {k: plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return type(value)(plain(v) for v in value)
    return value


def checkpoint_entry(role: str, net: nn.Module, datamodule: Any = None, loggers: Sequence[Any] = ()) -> dict[str, Any]:
    """The ``spade`` entry of a checkpoint: role, network config, the training windows, the MLflow run.

    ``datamodule``: the fit's data module; its ``image_size``, ``resolution`` and ``frame`` (the manifest's robot
    frame) are recorded when it has them, with the training set's disc radius and goal margin. ``loggers``: the
    module's loggers; an MLflow logger's run id is recorded (a resumed fit continues that run).
    """
    info: dict[str, Any] = {"role": str(role), "config": plain(dict(net.config))}
    if datamodule is not None and hasattr(datamodule, "resolution"):
        data: dict[str, Any] = {"image_size": [int(v) for v in datamodule.image_size],
                                "resolution_m": float(datamodule.resolution), "input_encoding": INPUT_ENCODING,
                                "marker_encoding": str(getattr(datamodule, "encoding", "binary"))}
        frame = getattr(datamodule, "frame", None)
        if frame:
            data["frame"] = plain(dict(frame))
        data.update(_annotation_geometry(datamodule))
        info["data"] = data
    for logger in loggers:
        if type(logger).__name__ == "MLFlowLogger" and getattr(logger, "run_id", None):
            info["mlflow_run_id"] = str(logger.run_id)
    return info


def _annotation_geometry(datamodule: Any) -> dict[str, float]:
    """``disc_radius_m`` and ``margin_m`` of the training windows, from the annotation settings the training set
    was generated with (the datamodule's ``annotation_settings``: its manifest's ``generator``), so that a planner
    draws the same start/goal discs and keeps goals as far inside the window; empty when the datamodule has no
    readable manifest."""
    try:
        generator = getattr(datamodule, "annotation_settings", None) or {}
    except Exception:  # no manifest yet, or not a SPADE dataset: the planner falls back to the annotation defaults
        return {}
    out: dict[str, Any] = {}
    for key, section, name in (("disc_radius_m", "instances", "disc_radius_m"), ("margin_m", "window", "margin_m")):
        value = (generator.get(section) or {}).get(name)
        if isinstance(value, (int, float)):
            out[key] = float(value)
    footprint = footprint_of(generator.get("robot"))
    if footprint:
        out["footprint"] = footprint
    return out


def footprint_of(robot: Any) -> dict[str, float] | None:
    """``{"radius_m", "inflation_radius_m"}`` of an annotation ``robot`` block (the robot the demonstrations'
    clearances assumed), or None when it does not hold both as numbers."""
    if not isinstance(robot, Mapping):
        return None
    values = {k: robot.get(k) for k in ("radius_m", "inflation_radius_m")}
    if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values.values()):
        return {k: float(v) for k, v in values.items()}
    return None


def write_checkpoint_entry(checkpoint: dict[str, Any], role: str, net: nn.Module, datamodule: Any = None,
                           loggers: Sequence[Any] = ()) -> None:
    """Fill a checkpoint being saved (Lightning's ``on_save_checkpoint``): the ``spade`` entry, and the
    hyper-parameters as plain data, so that :func:`load_checkpoint` opens it without allow-listing OmegaConf."""
    checkpoint[ENTRY_KEY] = checkpoint_entry(role, net, datamodule, loggers)
    if "hyper_parameters" in checkpoint:
        checkpoint["hyper_parameters"] = plain(dict(checkpoint["hyper_parameters"]))
        checkpoint.pop("hparams_type", None)  # a class object: only set for OmegaConf hyper-parameters


def export_metadata(info: Mapping[str, Any], fmt: str, *, source: str | Path, opset: int | None,
                    in_channels: int) -> dict[str, Any]:
    """The JSON an export carries: the checkpoint's entry (role, config, data with its robot frame, MLflow run)
    plus the export's format, source, torch version and tensor names/shapes. Refuses a checkpoint whose windows
    have no robot frame (:func:`robot_frame`)."""
    data = dict(info.get("data") or {})
    robot_frame(info, source)
    data.setdefault("input_encoding", INPUT_ENCODING)
    if not footprint_of(data.get("footprint")):
        # A checkpoint from before footprints were recorded: its data came from conf/annotate.yaml's robot unless
        # its user changed it; the export says it is assumed (the planner shows it so).
        data["footprint"] = {**DEFAULT_FOOTPRINT, "assumed": True}
    size = [int(v) for v in data["image_size"]]
    out = {
        "role": info.get("role"),
        "config": plain(dict(info["config"])),
        "data": plain(data),
        "source_checkpoint": str(Path(source).expanduser().resolve()),
        "torch_version": torch.__version__,
        "opset": opset if fmt == "onnx" else None,
        "format": fmt,
        "input": {"name": INPUT_NAME, "dtype": "float32", "shape": ["N", int(in_channels), *size]},
        "output": {"name": OUTPUT_NAME, "dtype": "float32", "shape": ["N", 1, *size],
                   "meaning": "path logits; sigmoid gives the path probability"},
    }
    if info.get("mlflow_run_id"):
        out["mlflow_run_id"] = info["mlflow_run_id"]
    return out


# -- reading ---------------------------------------------------------------------------------------------------
def _existing(path: str | Path, what: str = "model file") -> Path:
    p = Path(path).expanduser()
    if not p.is_file():
        raise FileNotFoundError(f"{what} {p} does not exist; pass a student or expert checkpoint written by "
                                "python -m spade.train (checkpoints/*.ckpt), or an export from python -m spade.export")
    return p


def _unsafe(path: Path, err: Exception) -> ModelFileError:
    found = re.search(r"GLOBAL (\S+)", str(err))
    if found is None:  # not a pickle of anything: a damaged file, or another format
        detail = re.search(r"WeightsUnpickler error:\s*(.*?)(?:\s+Check the documentation|$)", str(err), re.S)
        return ModelFileError(
            f"{path} is not a readable PyTorch checkpoint (the weights-only unpickler stopped: "
            f"{(detail.group(1) if detail else str(err)[-200:]).strip()}); pass a checkpoint written by python -m "
            "spade.train, or an export from python -m spade.export")
    what = f"the Python object {found.group(1)}"
    return UnsafeModelFileError(
        f"refused to load {path}: its pickle names {what}, which loading would construct or call (a checkpoint "
        "can run code this way). SPADE loads checkpoints with torch.load(weights_only=True): tensors, plain "
        "data and SPADE's allow-listed types only. If the file is not yours, do not use it; if it is and you "
        "trust it, save it again with only tensors and plain Python data in it (the checkpoints python -m "
        "spade.train writes are), or retrain"
    )


@contextlib.contextmanager
def safe_loading(path: str | Path) -> Iterator[None]:
    """Within the block, ``torch.load(..., weights_only=True)`` also accepts :data:`SAFE_GLOBALS`, and a pickle
    naming anything else raises :class:`UnsafeModelFileError` about ``path`` (not a bare ``UnpicklingError``).

    For checkpoints that other code opens: wrap ``Trainer.fit`` / ``Trainer.test`` called with ``ckpt_path=path``
    and ``weights_only=True``. The caller must pass ``weights_only=True`` itself.
    """
    try:
        with torch.serialization.safe_globals(SAFE_GLOBALS):
            yield
    except pickle.UnpicklingError as err:
        raise _unsafe(Path(path), err) from None


def load_checkpoint(path: str | Path, mmap: bool = False) -> dict[str, Any]:
    """A checkpoint's contents, read safely (see the module docstring), on the CPU. ``mmap``: map the tensors
    instead of reading them (for callers that only need the ``spade`` entry)."""
    p = _existing(path, "checkpoint")
    try:
        with safe_loading(p):
            checkpoint = torch.load(p, map_location="cpu", weights_only=True, mmap=mmap)
    except (RuntimeError, EOFError, OSError) as err:
        raise ModelFileError(f"{p} is not a readable PyTorch checkpoint ({type(err).__name__}: {err}); pass a "
                             "checkpoint written by python -m spade.train") from None
    if not isinstance(checkpoint, dict):
        raise ModelFileError(f"{p} holds a {type(checkpoint).__name__}, not a checkpoint dict; pass a checkpoint "
                             "written by python -m spade.train")
    return checkpoint


def load_lightning(cls: type, path: str | Path, **kwargs: Any) -> Any:
    """``cls.load_from_checkpoint(path)`` on the CPU with the same safe loading as :func:`load_checkpoint`."""
    p = _existing(path, "checkpoint")
    with safe_loading(p):
        return cls.load_from_checkpoint(p, map_location="cpu", weights_only=True, **kwargs)


def file_format(path: str | Path) -> str:
    """``checkpoint``, ``torchscript`` or ``onnx``, from the file's contents (not its name)."""
    p = _existing(path)
    if zipfile.is_zipfile(p):  # torch.save and TorchScript both write zip archives
        with zipfile.ZipFile(p) as archive:
            names = archive.namelist()
        if any(n.endswith("/constants.pkl") or "/code/" in n for n in names):
            return "torchscript"
        if any(n.endswith("/data.pkl") for n in names):
            return "checkpoint"
        raise ModelFileError(f"{p} is a zip file but neither a PyTorch checkpoint nor a TorchScript archive; pass a "
                             "checkpoint from python -m spade.train or an export from python -m spade.export")
    with open(p, "rb") as f:
        head = f.read(8)
    if head[:1] == b"\x80":  # a legacy (non-zip) torch.save pickle
        return "checkpoint"
    return "onnx"


def read_metadata(path: str | Path) -> dict[str, Any]:
    """The SPADE metadata of an exported ``.onnx`` or TorchScript file."""
    p = _existing(path, "export")
    fix = "export the student with python -m spade.export ckpt_path=<student .ckpt>"
    if zipfile.is_zipfile(p):  # TorchScript archives keep extra files under <archive>/extra/
        with zipfile.ZipFile(p) as archive:
            names = [n for n in archive.namelist() if n.endswith(f"/extra/{TORCHSCRIPT_METADATA_FILE}")]
            if not names:
                raise ModelFileError(f"{p} is a zip/TorchScript file without SPADE metadata "
                                     f"({TORCHSCRIPT_METADATA_FILE}): {fix}")
            return json.loads(archive.read(names[0]))
    onnx = _import("onnx")
    try:
        model = onnx.load(str(p), load_external_data=False)
    except Exception as err:  # protobuf raises several types on a file that is not ONNX
        raise ModelFileError(f"{p} is neither an ONNX nor a TorchScript file ({type(err).__name__}): {fix}") from None
    props = {e.key: e.value for e in model.metadata_props}
    if ENTRY_KEY not in props:
        raise ModelFileError(f"{p} carries no '{ENTRY_KEY}' metadata, so it is not a SPADE student export: {fix}")
    return json.loads(props[ENTRY_KEY])


def read_info(path: str | Path, *, checkpoint: bool = False, required: bool = True) -> dict[str, Any]:
    """The ``spade`` entry of any model file: a checkpoint's ``checkpoint["spade"]``, an export's metadata. The one
    reader of that entry: config checks, loading, resuming and fine-tuning all go through it.

    ``checkpoint=True``: the file must be a checkpoint (an export is refused as an unreadable one), for keys that
    take a ``.ckpt``. ``required=False``: a checkpoint without the entry gives ``{}`` (the caller says what it
    wanted) instead of :class:`ModelFileError`. A checkpoint's tensors are memory-mapped, not read.
    """
    p = _existing(path, "checkpoint" if checkpoint else "model file")
    if checkpoint or file_format(p) == "checkpoint":
        loaded = load_checkpoint(p, mmap=zipfile.is_zipfile(p))
        if not required:
            entry = loaded.get(ENTRY_KEY)
            return dict(entry) if isinstance(entry, Mapping) else {}
        return _entry(loaded, p)
    return read_metadata(p)


def _entry(checkpoint: Mapping[str, Any], path: Path) -> dict[str, Any]:
    info = checkpoint.get(ENTRY_KEY)
    if not isinstance(info, Mapping) or not info:
        raise ModelFileError(f"{path} is not a SPADE checkpoint (no '{ENTRY_KEY}' entry); pass one written by "
                             "python -m spade.train")
    return dict(info)


def require_role(info: Mapping[str, Any], role: str, path: str | Path) -> None:
    """Raise :class:`ModelFileError` unless the file holds a ``role`` model."""
    have = info.get("role")
    if have == role:
        return
    if role == "student":
        raise ModelFileError(
            f"{path} has role {have!r}, not 'student': diffusion experts are a training-time tool and are neither "
            "exported nor planned with; pass a student checkpoint (a BC / DBC / Cond-DBC run, e.g. "
            "+experiment=t1_medium_conddbc_L)")
    raise ModelFileError(f"{path} has role {have!r}, not {role!r}: pass a {role} checkpoint")


def untrained_student(size: str = "small", image_size: int = 64, resolution: float = 0.1, seed: int = 0
                      ) -> dict[str, Any]:
    """A student checkpoint as ``spade.train`` writes it (``torch.save`` it), with seeded untrained weights and the
    data record of a robot-frame window of ``image_size`` px at ``resolution`` m/px: what a bench or a probe plans
    with when the cost or the refusal is measured, not the plan."""
    torch.manual_seed(seed)
    net = build_model("student", size)
    data = {"image_size": [image_size, image_size], "resolution_m": resolution,
            "frame": RobotFrame.for_size(image_size).to_json()}
    return {ENTRY_KEY: {"role": "student", "config": dict(net.config), "data": data},
            "state_dict": {f"net.{k}": v for k, v in net.state_dict().items()}}


def robot_frame(info: Mapping[str, Any], path: str | Path) -> dict[str, Any]:
    """The robot frame (``data.frame``) a model was trained in; refuses a model without one."""
    data = info.get("data") or {}
    frame = data.get("frame") if isinstance(data, Mapping) else None
    if not isinstance(frame, Mapping) or frame.get("kind") != "robot":
        raise ModelFileError(
            f"{path} was trained on axis-aligned windows (its model file records no robot frame, data.frame): "
            f"the planner and exports need a robot-frame student. {RETRAIN[0].upper()}{RETRAIN[1:]}")
    for key in ("image_size", "resolution_m"):
        if data.get(key) is None:
            raise ModelFileError(f"{path} records a robot frame but no {key}: it was not written by SPADE; {RETRAIN}")
    return dict(frame)


# -- networks --------------------------------------------------------------------------------------------------
def build_network(info: Mapping[str, Any], state_dict: Mapping[str, torch.Tensor], path: str | Path) -> nn.Module:
    """The network a model file describes (``info["config"]``) with its weights (a Lightning state dict's
    ``net.`` entries, or a bare state dict), in eval mode on the CPU."""
    try:
        net = model_from_config(dict(info["config"]))
    except (KeyError, TypeError, ValueError) as err:
        raise ModelFileError(f"{path}: its network config {info.get('config')!r} is not one SPADE builds "
                             f"({err})") from None
    weights = {k[len("net."):]: v for k, v in state_dict.items() if k.startswith("net.")} or dict(state_dict)
    try:
        net.load_state_dict(weights)
    except RuntimeError as err:
        raise ModelFileError(f"{path}: its weights do not fit the network its config describes ({err})") from None
    return net.eval()


def load_network(path: str | Path, role: str | None = "student") -> tuple[nn.Module, dict[str, Any]]:
    """The network of a checkpoint (rebuilt from its config: neither the LightningModule nor the margin's expert is
    needed) and its ``spade`` entry."""
    p = _existing(path, "checkpoint")
    checkpoint = load_checkpoint(p)
    info = _entry(checkpoint, p)
    if role is not None:
        require_role(info, role, p)
    return build_network(info, checkpoint.get("state_dict") or {}, p), info


# -- running ---------------------------------------------------------------------------------------------------
def resolve_device(device: str | torch.device | None, cuda_available: bool | None = None) -> str:
    """The one device policy: ``cpu``, ``cuda`` / ``cuda:N`` (an error when there is no CUDA), or ``auto`` (CUDA
    when available, else the CPU). ``cuda_available`` overrides the check (a runtime's own provider list)."""
    available = torch.cuda.is_available() if cuda_available is None else cuda_available
    return device_name(device, available, ModelFileError, "no CUDA device is usable here: pass device=cpu (or "
                       "device=auto, which falls back to the CPU)")


class ModelRunner:
    """A student model file ready to run, whatever its kind: ``logits = runner(states)``.

    ``states`` (N, 3, H, W) float32 as numpy or torch; returns numpy float32 logits (N, 1, H, W). Attributes:
    ``path``, ``format`` (checkpoint / onnx / torchscript), ``runtime``, ``device``, ``info`` (the ``spade``
    entry or the export metadata), ``net`` (the rebuilt network, checkpoints only). ``allow_unsigned``: open an
    export without an integrity record (with a warning) instead of refusing it (:mod:`spade.models.onnx_check`).
    """

    def __init__(self, path: str | Path, device: str = "cpu", threads: int | None = None,
                 role: str | None = "student", allow_unsigned: bool = False) -> None:
        self.path = _existing(path)
        self.format = file_format(self.path)
        self.runtime = RUNTIMES[self.format]
        self.net: nn.Module | None = None
        if self.format == "checkpoint":
            self.device = resolve_device(device)
            net, self.info = load_network(self.path, role)
            self.net = net.to(self.device)
            return
        self.info = read_metadata(self.path)
        if role is not None:
            require_role(self.info, role, self.path)
        if self.format == "onnx":
            self._session = OnnxSession(self.path, device, threads, ModelFileError)
            self.device = self._session.device
        else:
            self.device = resolve_device(device)
            with warnings.catch_warnings():
                warnings.filterwarnings("ignore", category=DeprecationWarning)  # TorchScript is deprecated in 2.x
                self._module = torch.jit.load(str(self.path), map_location=self.device)
        self._check_export(allow_unsigned)

    def _check_export(self, allow_unsigned: bool) -> None:
        """An export is the one its metadata describes (:mod:`spade.models.onnx_check`): shapes, weight digest,
        parity probe, covered fields; else :class:`ModelFileError`. No record: refused unless ``allow_unsigned``."""
        if self.format == "onnx":
            shapes = self._session.input.shape, self._session.output.shape
            weights = lambda: weights_sha256(self.path.read_bytes())  # noqa: E731
        else:  # TorchScript keeps no shapes: the probe's output shape stands for them
            shapes = tuple((self.info.get(k) or {}).get("shape") for k in ("input", "output"))
            weights = lambda: archive_sha256(self.path)  # noqa: E731
        check_student_export(self.path, self.info, weights, *shapes, self, ModelFileError, allow_unsigned)

    def __call__(self, states: np.ndarray | torch.Tensor) -> np.ndarray:
        if self.format == "onnx":
            return self._session(states.detach().cpu().numpy() if isinstance(states, torch.Tensor) else states)
        x = states if isinstance(states, torch.Tensor) else torch.from_numpy(np.ascontiguousarray(states, np.float32))
        model = self.net if self.net is not None else self._module
        with torch.inference_mode():
            return model(x.to(self.device, torch.float32)).float().cpu().numpy()

    logits = __call__

    def __repr__(self) -> str:
        return f"ModelRunner({self.path.name}, {self.format} on {self.device})"


def open_model(path: str | Path, device: str = "cpu", threads: int | None = None,
               role: str | None = "student", allow_unsigned: bool = False) -> ModelRunner:
    """Open a checkpoint, ONNX or TorchScript student as a :class:`ModelRunner` (see there)."""
    return ModelRunner(path, device, threads, role, allow_unsigned)


def _import(name: str) -> Any:
    try:
        return __import__(name)
    except ImportError:  # pragma: no cover - depends on the installed extras
        raise ImportError(f"{name} is needed for ONNX files: pip install -e '.[onnx]'") from None
