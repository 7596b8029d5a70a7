"""``spade.export``'s checks: a student checkpoint in, an output (given or the default beside the checkpoint) that
is neither the checkpoint nor a folder and replaces only an export of SPADE's with ``overwrite=true``."""

from __future__ import annotations

import re
from dataclasses import dataclass, replace
from typing import Any, ClassVar

from omegaconf import DictConfig

from spade.config.checkpoint_checks import check_checkpoint
from spade.config.file_checks import input_file, output_file, same_file, check_paths
from spade.config.options import read_options
from spade.utils.errors import ConfigError
from spade.utils.option_checks import (check_bool_value, check_choice_value, check_int_list_value, check_int_value,
                                      check_number_value, unset)
from spade.config.store_checks import check_server, check_store_file


@dataclass(frozen=True)
class ExportOptions:
    """``spade.export``'s options (conf/export.yaml); the files they name: :func:`validate_export_config`."""

    node: ClassVar[str] = ""
    ckpt_path: Any = None
    format: str | None = "onnx"
    out_path: Any = None
    opset: int = 17
    parity_batch: int = 4
    tolerance: float | None = None
    latency_runs: int = 20
    latency_batches: tuple[int, ...] | None = (1,)
    threads: int | None = None
    register: Any = None
    alias: Any = None
    report_path: Any = None
    overwrite: bool | None = False
    store_uri: str | None = None  # with ``register``: the store it logs to (paths.mlflow_tracking_uri)

    def __post_init__(self) -> None:
        check_bool_value("overwrite", self.overwrite)
        check_int_value("opset", self.opset, 7, fix=", e.g. opset=17")
        check_int_value("parity_batch", self.parity_batch, 1)
        check_int_value("latency_runs", self.latency_runs, 0)
        check_int_list_value("latency_batches", self.latency_batches, 1, none_ok=True,
                             fix=", e.g. latency_batches=[1,8]")
        check_int_value("threads", self.threads, 1, none_ok=True, fix=" (null: all cores)")
        check_number_value("tolerance", self.tolerance, 0, none_ok=True, fix=" (null: only report)")

    @property
    def fmt(self) -> str:
        return self.format or "onnx"


@dataclass(frozen=True)
class StorePaths:
    """The project's MLflow store, where ``register=`` logs the export."""

    node: ClassVar[str] = "paths"
    mlflow_tracking_uri: str | None = None


def read_export_options(cfg: DictConfig) -> ExportOptions:
    """:class:`ExportOptions` of the composed config (with ``register``, the store it logs to); only these keys are
    resolved: ``paths.output_dir`` needs a running Hydra app, and ``spade.export`` works without."""
    options = read_options(cfg, ExportOptions)
    if unset(options.register):
        return options
    return replace(options, store_uri=read_options(cfg, StorePaths).mlflow_tracking_uri)


def validate_export_config(cfg: DictConfig) -> ExportOptions:
    """``spade.export``'s checks: a student checkpoint file in, an output that is not the checkpoint (nor a folder);
    returns the options the export runs with."""
    from spade.deploy.export import SUFFIXES  # heavy: the exporter imports spade.models (diffusers)

    check_paths(cfg)
    fix = "pass the student checkpoint (.ckpt) written by python -m spade.train"
    options = read_export_options(cfg)
    ckpt = input_file("ckpt_path", options.ckpt_path, fix)
    check_checkpoint("ckpt_path", str(ckpt), "student", fix)
    check_choice_value("format", options.format, list(SUFFIXES))
    fmt, overwrite, out = options.fmt, options.overwrite, options.out_path
    suffix = SUFFIXES[fmt]
    if unset(out):
        default = ckpt.with_suffix(suffix)
        if same_file(default, ckpt):
            raise ConfigError(f"ckpt_path={ckpt} ends with {suffix}: format={fmt} would write its export onto the "
                              f"checkpoint itself; set out_path={ckpt.with_name(ckpt.stem + '.' + fmt + suffix)}")
        # The default is checked as a given out_path is: an existing file there is replaced only when SPADE wrote it
        output_file("out_path", default, {"ckpt_path": ckpt}, f"set out_path to a new {suffix} file", (suffix,),
                     overwrite, label=f"out_path={default} (the default: the checkpoint's path with {suffix})")
    else:
        output_file("out_path", out, {"ckpt_path": ckpt}, f"set out_path to a new {suffix} file", (suffix,),
                     overwrite)
    if not unset(options.report_path):
        output_file("report_path", options.report_path, {"ckpt_path": ckpt}, "give a new .json file",
                     overwrite=overwrite)
    _check_register(options)
    return options


_RESERVED_ALIAS = re.compile(r"^(latest|v\d+)$", re.IGNORECASE)


def _reserved_alias_problem(alias: str) -> str | None:
    """MLflow's documented reservation: ``latest`` and ``v<digits>`` name versions, never aliases. Checked here
    because MLflow's private validator for it has changed name between releases (3.17 -> 3.18)."""
    if _RESERVED_ALIAS.match(alias):
        return f"'{alias}' is reserved by MLflow's registry for versions"
    return None


def _mlflow_name_problem(kind: str, value: str) -> str | None:
    """What MLflow's registry would say of a model ``kind`` (name / alias) ``value`` (None: accepted), asked of its
    own validators (under either release's names) before any export is written; the reserved aliases always."""
    if kind == "alias" and (problem := _reserved_alias_problem(value)) is not None:
        return problem
    try:
        from mlflow.exceptions import MlflowException
        from mlflow.utils import validation
    except ImportError:  # pragma: no cover - MLflow is a dependency
        return None
    checks = (["_validate_model_name"] if kind == "name"
              else ["_validate_model_alias_name", "_validate_alias_name", "_validate_model_alias_name_reserved",
                  "_validate_alias_name_reserved"])
    for name in checks:
        check = getattr(validation, name, None)
        if check is None:
            continue
        try:
            check(value)
        except MlflowException as exc:
            return str(getattr(exc, "message", exc)).splitlines()[0]
    return None


def _check_register(options: ExportOptions) -> None:
    """``register=`` (a registered model name, or null) and ``alias=``, checked before the export is written: a bad
    value used to fail after the export (one left a registered version without its alias)."""
    register = options.register
    if unset(register):
        return
    if not isinstance(register, str):
        raise ConfigError(f"register={register!r} is not a model name; set register=NAME (e.g. spade-student) or "
                          "register=null")
    if options.fmt != "onnx":
        raise ConfigError(f"register={register}: only ONNX exports are registered as MLflow Models; pass format=onnx "
                          "(or drop register=)")
    if (problem := _mlflow_name_problem("name", register)) is not None:
        raise ConfigError(f"register={register!r} is not a registered model name ({problem}); use letters, digits, "
                          "'-', '_' and '.', e.g. register=spade-student")
    alias = options.alias
    if alias not in (None, ""):
        if not isinstance(alias, str) or (problem := _mlflow_name_problem("alias", alias)) is not None:
            why = "not a string" if not isinstance(alias, str) else problem
            raise ConfigError(f"alias={alias!r} is not a model alias ({why}); use letters, digits, '_' and '-', e.g. "
                              "alias=champion, or alias=null for none")
    uri = options.store_uri
    if not unset(uri):
        check_store_file("paths.mlflow_tracking_uri", str(uri))
        check_server("paths.mlflow_tracking_uri", str(uri))
