"""``spade.bench``'s checks before any section runs: its own options and each section's sizes and counts, typed
per config node (conf/bench.yaml)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, make_dataclass
from typing import Any, ClassVar

from omegaconf import DictConfig

from spade.config.file_checks import output_file, check_paths
from spade.config.options import read_options
from spade.utils.errors import ConfigError
from spade.utils.option_checks import (MISSING, check_bool_value, check_int_list_value, check_int_value,
                                      check_number_value)

__all__ = ["BenchOptions", "SECTION_OPTIONS", "validate_bench_config"]


@dataclass(frozen=True)
class BenchOptions:
    """``spade.bench``'s own options: a boolean ``quick``, the ``sections`` to run, a thread count and seed, the
    results' ``out_json`` (checked against the files by :func:`validate_bench_config`) and ``speed_page``."""

    node: ClassVar[str] = ""
    quick: bool | None = False
    overwrite: bool | None = False
    out_json: Any = MISSING  # null is refused: the results are written there
    sections: Any = None
    threads: int | None = None
    seed: int = 0
    speed_page: Any = None

    def __post_init__(self) -> None:
        check_bool_value("quick", self.quick)
        check_bool_value("overwrite", self.overwrite)
        if self.out_json is None:
            raise ConfigError("out_json is not set; set out_json to a new .json file (the results are written there)")
        check_int_value("threads", self.threads, 1, none_ok=True, fix=" (null: all cores)")
        check_int_value("seed", self.seed, 0, 2**32 - 1)
        if self.speed_page is not None and not str(self.speed_page).endswith(".md"):
            raise ConfigError(f"speed_page={self.speed_page!r} is not a .md file; set speed_page=docs/results/speed.md "
                              "or null")


#: Each section's sizes and counts, by config node (null: the section's default): ``sizes`` a non-empty list of
#: integers >= 1 (a batch of 0 would print a latency for nothing), ``count`` an integer >= 1, ``count0`` one >= 0,
#: ``length`` a number > 0, ``flag`` a boolean, ``names`` a list of levers (checked by :func:`validate_bench_config`).
_SECTIONS: dict[str, dict[str, str]] = {
    "student": {"image_sizes": "sizes", "batches": "sizes", "runs": "count", "onnx": "flag"},
    "experts": {"ddim_steps": "sizes", "image_size": "count", "num_train_timesteps": "count",
                "max_timed_steps": "count"},
    "training": {"image_sizes": "sizes", "batch_size": "count", "runs": "count", "warmup": "count0",
                 "batched_terms": "flag", "lever_rounds": "count", "lever_image_size": "count", "matmul_size": "count",
                 "lightning_rounds": "count", "profile_top": "count", "lightning_steps": "count0", "levers": "names",
                 "profile_levers": "names", "evaluation_instances": "count0", "drive_scenarios": "count0"},
    "decoder": {"image_sizes": "sizes", "instances": "count"},
    "metrics": {"image_size": "count", "instances": "count", "fid_images": "count", "batch": "count",
                "sensitivity": "flag"},
    "data": {"window_px": "count", "train_instances": "count", "test_instances": "count", "workers": "count",
             "resolution_m": "length", "spacing_m": "length"},
    "quality": {"ddim_steps": "sizes", "samples": "count", "train_steps": "count", "num_train_timesteps": "count"},
    "annotation_scaling": {"image_sizes": "sizes", "workers": "sizes", "num_instances": "count"},
    "dataset": {"image_size": "count", "waypoints": "count"},
}
_TYPES = {"sizes": list[int] | None, "count": int | None, "count0": int | None, "length": float | None,
          "flag": bool | None, "names": list[str] | None}
_FIXES = {"training.lightning_steps": " (0: no Lightning overhead table)",
          "training.evaluation_instances": " (0: no test pass timed)",
          "training.drive_scenarios": " (0: no closed-loop drive timed)"}


def _check_section(options: Any) -> None:
    """A section's options typed and ranged by their kind in :data:`_SECTIONS`."""
    for name, kind in _SECTIONS[options.node].items():
        key, value = f"{options.node}.{name}", getattr(options, name)
        if kind == "sizes":
            check_int_list_value(key, value, 1, none_ok=True)
        elif kind in ("count", "count0"):
            check_int_value(key, value, 1 if kind == "count" else 0, none_ok=True, fix=_FIXES.get(key, ""))
        elif kind == "length":
            check_number_value(key, value, 0, low_open=True, none_ok=True)
        elif kind == "flag":
            check_bool_value(key, value)


#: The sections' options, one frozen dataclass per config node (``student``, ``experts``, ...), each checking its
#: fields at construction.
SECTION_OPTIONS = tuple(
    make_dataclass(f"{node.title().replace('_', '')}Bench", [(name, _TYPES[kind], None) for name, kind in spec.items()],
                   namespace={"node": node, "__post_init__": _check_section}, frozen=True)
    for node, spec in _SECTIONS.items())


def _check_names(key: str, value: Any, known: Sequence[str], example: str, use: str) -> None:
    """A list of names among ``known`` (null: the default); ``use`` says how to name some of them."""
    if value is None or not known:
        return
    if isinstance(value, str) or not isinstance(value, list):
        raise ConfigError(f"{key}={value!r} is not a list; use {key}=[{example}]")
    unknown = sorted({str(x) for x in value} - set(known))
    if unknown:
        raise ConfigError(f"{key}: unknown {', '.join(unknown)}; use {use}some of {', '.join(known)}")


def validate_bench_config(cfg: DictConfig, known_sections: Sequence[str],
                          known_levers: Sequence[str] = ()) -> BenchOptions:
    """``spade.bench``'s checks before any section runs: :class:`BenchOptions` and each section's options, the
    ``sections`` among ``known_sections`` and the levers among ``known_levers`` (:data:`spade.perf.bench.SECTIONS`
    and :data:`spade.perf.training.LEVERS`, passed in: the benchmark sits on a higher floor), and an ``out_json``
    (given or the default) that replaces only an earlier benchmark's JSON, with ``overwrite=true``."""
    check_paths(cfg)
    options = read_options(cfg, BenchOptions)
    if options.out_json is not MISSING:
        output_file("out_json", options.out_json, {}, "set out_json to a new .json file", (".json",),
                     options.overwrite)
    _check_names("sections", options.sections, known_sections, ",".join(list(known_sections)[:2]),
                 "sections=[...] with ")
    for section in SECTION_OPTIONS:
        built = read_options(cfg, section)
        if section.node == "training":
            for key in ("levers", "profile_levers"):
                _check_names(f"training.{key}", getattr(built, key), known_levers,
                             ",".join(list(known_levers)[1:3]), "")
    return options
