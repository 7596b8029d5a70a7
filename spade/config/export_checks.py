"""``spade.export``'s checks: a student checkpoint in, an output (given or the default beside the checkpoint) that
is neither the checkpoint nor a folder and replaces only an export of SPADE's with ``overwrite=true``."""

from __future__ import annotations

import re

from omegaconf import DictConfig

from spade.config.checkpoint_checks import check_checkpoint
from spade.config.file_checks import input_file, output_file, same_file, check_paths
from spade.config.values import check_bool, check_choice, check_int, check_int_list, check_number, get
from spade.utils.errors import ConfigError
from spade.utils.option_checks import MISSING, unset


def validate_export_config(cfg: DictConfig) -> None:
    """``spade.export``'s checks: a student checkpoint file in, an output that is not the checkpoint (nor a folder)."""
    from spade.deploy.export import SUFFIXES  # heavy: the exporter imports spade.models (diffusers)

    check_paths(cfg)
    fix = "pass the student checkpoint (.ckpt) written by python -m spade.train"
    ckpt = input_file("ckpt_path", get(cfg, "ckpt_path"), fix)
    check_checkpoint("ckpt_path", str(ckpt), "student", fix)
    check_choice(cfg, "format", list(SUFFIXES))
    fmt = get(cfg, "format")
    fmt = "onnx" if fmt in (MISSING, None) else fmt
    check_bool(cfg, "overwrite")
    overwrite = get(cfg, "overwrite")
    out = get(cfg, "out_path")
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
    check_int(cfg, "opset", 7, fix=", e.g. opset=17")
    check_int(cfg, "parity_batch", 1)
    check_int(cfg, "latency_runs", 0)
    check_int_list(cfg, "latency_batches", 1, none_ok=True, fix=", e.g. latency_batches=[1,8]")
    check_int(cfg, "threads", 1, none_ok=True, fix=" (null: all cores)")
    check_number(cfg, "tolerance", 0, none_ok=True, fix=" (null: only report)")
    report = get(cfg, "report_path")
    if not unset(report):
        output_file("report_path", report, {"ckpt_path": ckpt}, "give a new .json file", overwrite=overwrite)
    _check_register(cfg, fmt)


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


def _check_register(cfg: DictConfig, fmt: str) -> None:
    """``register=`` (a registered model name, or null) and ``alias=``, checked before the export is written: a bad
    value used to fail after the export (one left a registered version without its alias)."""
    register = get(cfg, "register")
    if unset(register):
        return
    if not isinstance(register, str):
        raise ConfigError(f"register={register!r} is not a model name; set register=NAME (e.g. spade-student) or "
                          "register=null")
    if fmt != "onnx":
        raise ConfigError(f"register={register}: only ONNX exports are registered as MLflow Models; pass format=onnx "
                          "(or drop register=)")
    if (problem := _mlflow_name_problem("name", register)) is not None:
        raise ConfigError(f"register={register!r} is not a registered model name ({problem}); use letters, digits, "
                          "'-', '_' and '.', e.g. register=spade-student")
    alias = get(cfg, "alias")
    if alias not in (MISSING, None, ""):
        if not isinstance(alias, str) or (problem := _mlflow_name_problem("alias", alias)) is not None:
            why = "not a string" if not isinstance(alias, str) else problem
            raise ConfigError(f"alias={alias!r} is not a model alias ({why}); use letters, digits, '_' and '-', e.g. "
                              "alias=champion, or alias=null for none")
    from spade.config.store_checks import check_server, check_store_file

    uri = get(cfg, "paths.mlflow_tracking_uri")
    if not unset(uri):
        check_store_file("paths.mlflow_tracking_uri", str(uri))
        check_server("paths.mlflow_tracking_uri", str(uri))
