"""Whether an ONNX student is the export its ``spade`` metadata describes: what the export records, and the check.

Copying a real export's ``spade`` metadata onto another graph (an Identity graph, say) used to give a file every
reader accepted: its role, window and frame were all there. ``python -m spade.export`` now also records, in the
metadata's ``integrity`` entry (:func:`integrity_record`):

- ``weights_sha256``: the sha256 of the graph's initializers (its weights) as the file serializes them, read from
  the protobuf wire format (:func:`weights_sha256`), so that the torch-free deploy install (no ``onnx`` package)
  computes it too;
- ``probe``: the network's output on a fixed input (:func:`probe_state`, batch 1, the model's input shape, made
  from ``seed`` by integer arithmetic alone, so that numpy versions cannot change it), kept compactly: its shape,
  mean, sd, min and max, and :data:`PROBE_SAMPLES` evenly spaced values (float32, base64);
- ``fields``: a digest of each metadata field a planner acts on (:func:`fields_record`, :func:`covered_fields`):
  the role, the network config, the tensor shapes, the format, and every entry of ``data`` (window size and
  resolution, robot frame, input and marker encodings, disc radius, goal margin, footprint), so that editing one
  (``data.resolution_m`` 0.1 -> 0.05 would rescale every plan) is refused, naming the field.

A TorchScript export carries the same record in its ``spade.json``, its ``weights_sha256`` taken over the
archive's code and tensors (:func:`archive_sha256`).

Opening an ONNX student (:class:`spade.models.modelfile.ModelRunner`, :class:`spade.deploy.onnx_runtime.OnnxRunner`)
runs :func:`check_onnx_student`: the graph's input and output shapes against the metadata's, the weight digest
recomputed, and the probe run and compared (:data:`PROBE_ATOL`, :data:`PROBE_RTOL`: runtimes and devices agree far
closer than that, another network does not), and the covered fields' digests compared. A mismatch is refused,
naming the file (and the field): it was not written by ``spade.export``, or was changed since.

A file trusted only as far as it is signed: one without an ``integrity`` record (another tool's metadata copied
onto a graph, or an export from before the records) is refused unless its user
opts in by name (``allow_unsigned=True``; it then opens with an :class:`UncheckedExportWarning`, its shapes still
checked). A record from before ``fields`` (weights and probe only) opens with a warning naming the fields it does
not cover, provided the window its probe records is the metadata's.

This is a consistency check, not a cryptographic signature: it refuses a graph that carries another export's
metadata, and a file damaged or edited since its export; whoever rewrites the records as well is not stopped.

Torch-free on purpose (numpy, hashlib): the deploy install imports it.
"""

from __future__ import annotations

import base64
import hashlib
import json
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["ALLOW_UNSIGNED", "INTEGRITY_KEY", "UncheckedExportWarning", "archive_sha256",
           "check_onnx_student", "check_student_export", "covered_fields", "fields_record", "integrity_record",
           "probe_record", "probe_state", "weights_sha256"]

INTEGRITY_KEY = "integrity"  # the metadata entry holding the records below
PROBE_SEED = 0
PROBE_SAMPLES = 64  # output values kept (evenly spaced over the flattened output)
PROBE_ATOL = PROBE_RTOL = 1e-2
"""A probe value matches when ``|got - recorded| <= PROBE_ATOL + PROBE_RTOL * |recorded|``: float32 reorderings
between PyTorch, onnxruntime and devices (TF32 included) stay well inside it; another network's logits do not."""
REEXPORT = "re-export it from its student checkpoint: python -m spade.export ckpt_path=<student .ckpt>"
ALLOW_UNSIGNED = ("allow_unsigned=true to use it unchecked (Planner(..., allow_unsigned=True); spade.plan and "
                  "spade.ros: planner.allow_unsigned=true; spade.sketch: allow_unsigned=true)")
COVERED_KEYS = ("role", "config", "format", "input", "output")
"""Top-level metadata fields the ``fields`` record covers; with them every entry of ``data`` (``data.<key>``) and
the :data:`PLANNER_DATA_KEYS` even where absent (a planner falls back to a default for a missing one, so adding
one later changes its plans too). Provenance (``source_checkpoint``, ``torch_version``, ``opset``,
``mlflow_run_id``) is not covered: no planner acts on it."""
PLANNER_DATA_KEYS = ("image_size", "resolution_m", "frame", "input_encoding", "marker_encoding", "disc_radius_m",
                     "margin_m", "footprint")

# ONNX protobuf field numbers (onnx/onnx.proto): ModelProto.graph, GraphProto.initializer / sparse_initializer
_MODEL_GRAPH, _GRAPH_INITIALIZER, _GRAPH_SPARSE_INITIALIZER = 7, 5, 15


class UncheckedExportWarning(UserWarning):
    """A student export opened without the full check: its user allowed an unsigned file (``allow_unsigned``), or
    its record predates the ``fields`` digests."""


# -- the records -------------------------------------------------------------------------------------------------
def _varint(buf: memoryview, i: int) -> tuple[int, int]:
    value, shift = 0, 0
    while True:
        if i >= len(buf) or shift > 63:
            raise ValueError("truncated or malformed varint")
        byte = buf[i]
        i += 1
        value |= (byte & 0x7F) << shift
        shift += 7
        if not byte & 0x80:
            return value, i


def _fields(buf: memoryview) -> Iterator[tuple[int, memoryview | None]]:
    """(field number, bytes of a length-delimited field or None) of one protobuf message, in order."""
    i = 0
    while i < len(buf):
        key, i = _varint(buf, i)
        number, wire = key >> 3, key & 7
        value: memoryview | None = None
        if wire == 0:
            _, i = _varint(buf, i)
        elif wire == 1:
            i += 8
        elif wire == 2:
            size, i = _varint(buf, i)
            value = buf[i:i + size]
            i += size
        elif wire == 5:
            i += 4
        else:  # groups (3, 4) are not used by ONNX
            raise ValueError(f"unsupported protobuf wire type {wire}")
        if i > len(buf):
            raise ValueError("truncated protobuf message")
        yield number, value


def weights_sha256(model: bytes | memoryview) -> str:
    """The sha256 of an ONNX model's initializers (dense and sparse), in file order, each as it is serialized
    (name, dims, type and data) with its length: the weights, without the ``onnx`` package. Raises ValueError on
    bytes that are not a serialized ModelProto with a graph."""
    graph = None
    for number, value in _fields(memoryview(model)):
        if number == _MODEL_GRAPH and value is not None:
            graph = value
    if graph is None:
        raise ValueError("no graph in the model")
    digest = hashlib.sha256()
    for number, value in _fields(graph):
        if number in (_GRAPH_INITIALIZER, _GRAPH_SPARSE_INITIALIZER) and value is not None:
            digest.update(number.to_bytes(1, "little") + len(value).to_bytes(8, "little"))
            digest.update(value)
    return digest.hexdigest()


def _splitmix64(x: np.ndarray) -> np.ndarray:
    """SplitMix64 of each uint64 (numpy wraps array arithmetic modulo 2**64)."""
    x = x + np.uint64(0x9E3779B97F4A7C15)
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


def probe_state(shape: Sequence[int], seed: int = PROBE_SEED) -> np.ndarray:
    """The probe's input, float32 of ``shape`` (N, C, H, W), in the network's encoding: channel 0 occupancy codes
    0 / 0.5 / 1 (1 : 3 : 1), every other channel one disc. Made by integer arithmetic (SplitMix64) rather than
    numpy's generators, whose streams may change between numpy versions: export and deploy machines agree."""
    n, c, h, w = (int(v) for v in shape)
    counter = np.arange(n * h * w, dtype=np.uint64) + np.uint64((int(seed) * 0x632BE59BD9B4E019) % 2**64)
    u = (_splitmix64(counter) >> np.uint64(11)).astype(np.float64) * 2.0**-53
    state = np.zeros((n, c, h, w), dtype=np.float32)
    state[:, 0] = np.where(u < 0.2, 0.0, np.where(u < 0.8, 0.5, 1.0)).reshape(n, h, w)
    rows, cols = np.mgrid[:h, :w]
    radius = max(1.0, min(h, w) / 32)
    for channel in range(1, c):  # the start, goal (and any further marker) discs, at fixed places
        r = radius + (h - 2 * radius) * ((0.25 + 0.618034 * channel) % 1.0)
        q = radius + (w - 2 * radius) * ((0.75 + 0.381966 * channel) % 1.0)
        state[:, channel] = ((rows - r) ** 2 + (cols - q) ** 2 <= radius**2).astype(np.float32)
    return state


def _sample_index(size: int) -> np.ndarray:
    return np.unique(np.linspace(0, size - 1, min(PROBE_SAMPLES, size)).round().astype(np.int64))


def probe_record(input_shape: Sequence[int], output: np.ndarray, seed: int = PROBE_SEED) -> dict[str, Any]:
    """The ``probe`` record of a network's ``output`` on ``probe_state(input_shape, seed)``."""
    flat = np.asarray(output, dtype=np.float32).ravel()
    return {"seed": int(seed), "input_shape": [int(v) for v in input_shape],
            "output_shape": [int(v) for v in np.shape(output)],
            **{k: float(f(flat.astype(np.float64))) for k, f in (("mean", np.mean), ("std", np.std), ("min", np.min),
                                                                 ("max", np.max))},
            "samples": base64.b64encode(flat[_sample_index(flat.size)].astype("<f4").tobytes()).decode("ascii")}


def archive_sha256(path: Path) -> str:
    """The sha256 of a TorchScript archive's code, constants and tensors: every entry but ``extra/`` (the metadata
    itself) and ``.data/`` (``serialization_id`` differs on every save), by name with its length. The torch-free
    counterpart of :func:`weights_sha256` for ``.pt`` exports."""
    import zipfile

    digest = hashlib.sha256()
    with zipfile.ZipFile(path) as archive:
        named = sorted((n.split("/", 1)[1], n) for n in archive.namelist() if "/" in n)
        for name, full in named:
            if name.startswith(("extra/", ".data/")) or name.endswith("/"):
                continue
            value = archive.read(full)
            digest.update(name.encode() + b"\0" + len(value).to_bytes(8, "little"))
            digest.update(value)
    return digest.hexdigest()


def covered_fields(metadata: Mapping[str, Any]) -> dict[str, Any]:
    """The metadata fields a planner acts on, by dotted name (:data:`COVERED_KEYS`, ``data.<key>``), with their
    values (None where absent)."""
    data = metadata.get("data")
    data = data if isinstance(data, Mapping) else {}
    out: dict[str, Any] = {key: metadata.get(key) for key in COVERED_KEYS}
    out.update({f"data.{key}": data.get(key) for key in sorted({*PLANNER_DATA_KEYS, *map(str, data)})})
    return out


def _field_digest(value: Any) -> str:
    return hashlib.sha256(json.dumps(value, sort_keys=True, separators=(",", ":")).encode()).hexdigest()[:32]


def fields_record(metadata: Mapping[str, Any]) -> dict[str, str]:
    """The ``fields`` record: a digest of each of :func:`covered_fields`' values, by name."""
    return {name: _field_digest(value) for name, value in covered_fields(metadata).items()}


def integrity_record(model: bytes | str, probe: Mapping[str, Any], metadata: Mapping[str, Any]) -> dict[str, Any]:
    """The ``integrity`` entry of an export: the weight digest (of the serialized ONNX ``model``, or a TorchScript
    :func:`archive_sha256` given as a str), the ``probe``, and the ``fields`` digests of ``metadata``."""
    digest = model if isinstance(model, str) else weights_sha256(model)
    return {"weights_sha256": digest, "probe": dict(probe), "fields": fields_record(metadata)}


# -- the check ---------------------------------------------------------------------------------------------------
def _shape_mismatch(what: str, graph: Sequence[Any], recorded: Any) -> str | None:
    """Why the graph's ``what`` shape disagrees with the recorded one (None where it agrees or nothing is recorded);
    the recorded batch axis is a name ("N"): any graph dimension fits it."""
    if not isinstance(recorded, Sequence) or isinstance(recorded, str):
        return None
    graph = list(graph)
    fits = len(graph) == len(recorded) and all(
        isinstance(r, str) or (isinstance(g, int) and g == r) for g, r in zip(graph, recorded))
    return None if fits else f"its graph's {what} has shape {graph}, its metadata records {list(recorded)}"


def _close(got: np.ndarray | float, recorded: np.ndarray | float) -> bool:
    return bool(np.all(np.abs(np.asarray(got) - np.asarray(recorded)) <= PROBE_ATOL + PROBE_RTOL * np.abs(recorded)))


def _probe_mismatch(probe: Mapping[str, Any], run: Callable[[np.ndarray], np.ndarray]) -> str | None:
    """Run the recorded probe; why its output differs from the record (None where it matches)."""
    try:
        state = probe_state(probe["input_shape"], int(probe["seed"]))
        recorded = np.frombuffer(base64.b64decode(probe["samples"]), dtype="<f4")
        summary = {k: float(probe[k]) for k in ("mean", "std", "min", "max")}
        expected_shape = [int(v) for v in probe["output_shape"]]
    except (KeyError, TypeError, ValueError) as err:
        return f"its probe record is malformed ({type(err).__name__}: {err})"
    try:
        output = np.asarray(run(state), dtype=np.float64)
    except Exception as err:  # noqa: BLE001 - the runtime's own error types: the graph does not take the probe
        return f"it does not run on the recorded probe input of shape {list(state.shape)} ({type(err).__name__})"
    if list(output.shape) != expected_shape:
        return f"its output on the probe has shape {list(output.shape)}, the export's had {expected_shape}"
    flat = output.ravel()
    got = flat[_sample_index(flat.size)]
    got_summary = {"mean": flat.mean(), "std": flat.std(), "min": flat.min(), "max": flat.max()}
    if got.shape != recorded.shape or not _close(got, recorded) or not all(
            _close(got_summary[k], v) for k, v in summary.items()):
        diff = float(np.max(np.abs(got - recorded))) if got.shape == recorded.shape else float("nan")
        return (f"its output on the parity probe differs from the one recorded at export (max |difference| "
                f"{diff:.3g} over {recorded.size} sampled values; mean {got_summary['mean']:.4g} vs "
                f"{summary['mean']:.4g})")
    return None


def _short(value: Any) -> str:
    text = json.dumps(value, sort_keys=True)
    return text if len(text) <= 60 else text[:57] + "..."


def _fields_mismatch(info: Mapping[str, Any], recorded: Any) -> str | None:
    """Why the metadata's covered fields are not the ones signed at export (None where they all are): the names
    of the fields edited, added or removed since."""
    if not isinstance(recorded, Mapping):
        return f"its metadata's {INTEGRITY_KEY}.fields record is malformed"
    values, now = covered_fields(info), fields_record(info)
    changed = [name for name in sorted(set(now) | set(recorded)) if now.get(name) != recorded.get(name)]
    if not changed:
        return None
    what = []
    for name in changed:
        if name not in recorded:
            what.append(f"{name} (= {_short(values.get(name))}) was not in its metadata at export")
        elif name not in now:
            what.append(f"{name} was removed since export")
        else:
            what.append(f"{name} (= {_short(values.get(name))}) is not the value signed at export")
    return f"its metadata was edited: {'; '.join(what)}"


def _old_record_mismatch(info: Mapping[str, Any], probe: Mapping[str, Any]) -> str | None:
    """For a record from before ``fields``: whether the window its probe records (``input_shape`` [1, C, H, W]) is
    the metadata's (``data.image_size``, the input channels); None where it is."""
    try:
        _, channels, *size = (int(v) for v in probe["input_shape"])
    except (KeyError, TypeError, ValueError):
        return "its probe record is malformed"
    data = info.get("data") if isinstance(info.get("data"), Mapping) else {}
    image_size = data.get("image_size")
    if isinstance(image_size, Sequence) and [v for v in image_size] != size:
        return (f"its metadata was edited: data.image_size (= {_short(image_size)}) is not the {size} window its "
                f"parity probe was recorded on")
    shape = (info.get("input") or {}).get("shape") if isinstance(info.get("input"), Mapping) else None
    if isinstance(shape, Sequence) and len(shape) > 1 and shape[1] != channels:
        return f"its metadata was edited: input.shape has {shape[1]} channels, its parity probe {channels}"
    return None


def check_student_export(path: Path, info: Mapping[str, Any], weights: Callable[[], str],
                         input_shape: Sequence[Any], output_shape: Sequence[Any],
                         run: Callable[[np.ndarray], np.ndarray], error: type[Exception],
                         allow_unsigned: bool = False) -> None:
    """Refuse (``error``, naming ``path``) a student export (ONNX or TorchScript) that is not the one its metadata
    ``info`` describes: input and output shapes (the runtime's, ``input_shape`` / ``output_shape``), the weight
    digest (``weights()``: :func:`weights_sha256` of an ONNX file, :func:`archive_sha256` of a TorchScript one;
    called only when a digest is recorded), the parity probe (``run``: the runner's ``logits``) and the covered
    fields' digests. A file without an ``integrity`` record is refused unless ``allow_unsigned`` (then: an
    :class:`UncheckedExportWarning`); a record without ``fields`` opens with that warning."""
    why = (_shape_mismatch("input", input_shape, (info.get("input") or {}).get("shape"))
           or _shape_mismatch("output", output_shape, (info.get("output") or {}).get("shape")))
    integrity = info.get(INTEGRITY_KEY)
    if why is None and integrity is None:
        missing = (f"{path} carries no {INTEGRITY_KEY} record in its SPADE metadata (the weight digest, parity probe "
                   f"and field digests python -m spade.export writes), so nothing ties its graph, window, "
                   f"resolution or footprint to what was trained")
        if not allow_unsigned:
            raise error(f"{missing}: refused. {REEXPORT[0].upper()}{REEXPORT[1:]}, or pass {ALLOW_UNSIGNED}")
        warnings.warn(UncheckedExportWarning(f"{missing}; opened unchecked (allow_unsigned=true). {REEXPORT}"),
                      stacklevel=3)
        return
    if why is None and not (isinstance(integrity, Mapping) and isinstance(integrity.get("probe"), Mapping)):
        why = f"its metadata's {INTEGRITY_KEY} record is malformed"
    if why is None:
        why = (_fields_mismatch(info, integrity["fields"]) if "fields" in integrity
               else _old_record_mismatch(info, integrity["probe"]))
    if why is None:
        try:
            digest = weights()
        except (ValueError, OSError) as err:
            digest = f"unreadable ({err})"
        if digest != integrity.get("weights_sha256"):
            why = "its weights do not match the digest its metadata records (weights_sha256)"
    if why is None:
        why = _probe_mismatch(integrity["probe"], run)
    if why is not None:
        raise error(f"{path} is not the export its SPADE metadata describes: {why}. It was not written by "
                    f"python -m spade.export (or was changed since); do not use it: {REEXPORT}")
    if "fields" not in integrity:
        uncovered = ", ".join(f"data.{k}" for k in PLANNER_DATA_KEYS if k != "image_size")
        warnings.warn(UncheckedExportWarning(
            f"{path}: its integrity record (from an older SPADE) covers its weights and window size but not "
            f"{uncovered}: those are unchecked; {REEXPORT} to have them checked"), stacklevel=3)


def check_onnx_student(path: Path, info: Mapping[str, Any], model: Callable[[], bytes],
                       input_shape: Sequence[Any], output_shape: Sequence[Any],
                       run: Callable[[np.ndarray], np.ndarray], error: type[Exception],
                       allow_unsigned: bool = False) -> None:
    """:func:`check_student_export` of an ONNX file, whose weight digest is :func:`weights_sha256` of its bytes
    (``model()``)."""
    check_student_export(path, info, lambda: weights_sha256(model()), input_shape, output_shape, run, error,
                         allow_unsigned)
