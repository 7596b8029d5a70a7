"""``python -m spade.export ckpt_path=PATH [format=onnx|torchscript]``: deploy a trained student as one file.

Writes the student with its metadata (window size, metres per pixel, robot frame, input encoding, network config),
checks that the file reproduces PyTorch's logits (prints the max absolute difference) and prints eager and exported
latency. ``register=NAME`` also logs the ONNX export as an MLflow Model (ONNX flavour, with its signature and window
metadata) in the project's store, registers it as NAME and sets ``alias`` (``champion``) on the new version:
``python -m spade.plan ... model=models:/NAME@champion`` and ``python -m spade.ros model=models:/NAME@champion``
then load it (:mod:`spade.deploy.mlflow_models`). See ``conf/export.yaml`` for the options and
:mod:`spade.deploy.export` for the file format. Inputs are checked first; a user error is one ``error:`` line, exit 2."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import hydra
from omegaconf import DictConfig

from spade.paths import CONFIG_PATH  # the configs (conf/ or the installed copy); registers the resolvers
from spade.utils.errors import ConfigError, run_entry_point, task
from spade.deploy.export import ExportReport, export_student
from spade.config.export_checks import ExportOptions, validate_export_config
from spade.config.refusals import exit_on_user_error
from spade.deploy.mlflow_models import register_onnx_student

log = logging.getLogger(__name__)


def export(cfg: DictConfig) -> ExportReport:
    """Check the config (:func:`~spade.config.export_checks.validate_export_config`: a student checkpoint in, an
    output that is neither it nor a folder), then run :func:`export_with` with its options."""
    return export_with(validate_export_config(cfg))


def export_with(options: ExportOptions) -> ExportReport:
    """:func:`~spade.deploy.export.export_student` with checked ``options``; with ``register``, the ONNX export
    logged and registered in the store, and with ``report_path`` the report written as JSON."""
    report = export_student(
        options.ckpt_path,
        options.out_path,
        options.fmt,
        opset=int(options.opset),
        parity_batch=int(options.parity_batch),
        tolerance=options.tolerance,
        latency_runs=int(options.latency_runs),
        latency_batches=tuple(options.latency_batches or (1,)),
        threads=options.threads,
    )
    if options.register:
        if report.format != "onnx":
            raise ConfigError(f"register={options.register}: only ONNX exports are registered as MLflow Models; "
                              "pass format=onnx")
        registered = register_onnx_student(report.out_path, str(options.register), options.alias or None,
                                           tracking_uri=options.store_uri)
        log.info("registered as %s (version %s)", registered.model_uri, registered.version)
        print(f"registered: {registered.model_uri} (version {registered.version}, run {registered.run_id})")
    if options.report_path:
        path = Path(options.report_path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(report.to_dict(), indent=2))
        log.info("report written to %s", path)
    return report


@hydra.main(version_base="1.3", config_path=CONFIG_PATH, config_name="export")
@task
def main(cfg: DictConfig) -> None:
    print(exit_on_user_error(export)(cfg).summary())  # a user error: one `error:` line, exit 2


if __name__ == "__main__":
    run_entry_point(main)
