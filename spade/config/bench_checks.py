"""``spade.bench``'s checks before any section runs."""

from __future__ import annotations

from collections.abc import Sequence

from omegaconf import DictConfig

from spade.config.file_checks import output_file, check_paths
from spade.config.values import check_bool, check_int, check_int_list, check_number, get
from spade.utils.errors import ConfigError
from spade.utils.option_checks import MISSING


def validate_bench_config(cfg: DictConfig, known_sections: Sequence[str], known_levers: Sequence[str] = ()) -> None:
    """``spade.bench``'s checks before any section runs: ``quick`` a boolean, ``sections`` among ``known_sections``
    (:data:`spade.perf.bench.SECTIONS`, passed in: the benchmark sits on a higher floor), a thread count, and an
    ``out_json`` (given or the default) that replaces only an earlier benchmark's JSON, with ``overwrite=true``."""
    check_bool(cfg, "quick")
    check_paths(cfg)
    check_bool(cfg, "overwrite")
    out = get(cfg, "out_json")
    if out is not MISSING:
        if out is None:
            raise ConfigError("out_json is not set; set out_json to a new .json file (the results are written there)")
        output_file("out_json", out, {}, "set out_json to a new .json file", (".json",), get(cfg, "overwrite"))
    sections = get(cfg, "sections")
    if sections is not MISSING and sections is not None:
        if isinstance(sections, str) or not isinstance(sections, list):
            raise ConfigError(f"sections={sections!r} is not a list; use sections=[{','.join(list(known_sections)[:2])}]")
        unknown = sorted({str(x) for x in sections} - set(known_sections))
        if unknown:
            raise ConfigError(f"sections: unknown {', '.join(unknown)}; use sections=[...] with some of "
                              f"{', '.join(known_sections)}")
    check_int(cfg, "threads", 1, none_ok=True, fix=" (null: all cores)")
    check_int(cfg, "seed", 0, 2**32 - 1)
    # sizes and counts of the sections: a batch of 0 would print a latency for nothing
    for key in ("student.image_sizes", "student.batches", "experts.ddim_steps", "training.image_sizes",
                "decoder.image_sizes", "quality.ddim_steps", "annotation_scaling.image_sizes",
                "annotation_scaling.workers"):
        check_int_list(cfg, key, 1, none_ok=True)
    for key in ("student.runs", "experts.image_size", "experts.num_train_timesteps", "experts.max_timed_steps",
                "training.batch_size", "training.runs", "decoder.instances", "metrics.image_size",
                "metrics.instances", "metrics.fid_images", "metrics.batch", "data.window_px", "data.train_instances",
                "data.test_instances", "data.workers", "quality.samples", "quality.train_steps",
                "quality.num_train_timesteps", "annotation_scaling.num_instances", "dataset.image_size",
                "dataset.waypoints"):
        check_int(cfg, key, 1, none_ok=True)
    check_int(cfg, "training.warmup", 0, none_ok=True)
    check_number(cfg, "data.resolution_m", 0, low_open=True, none_ok=True)
    check_number(cfg, "data.spacing_m", 0, low_open=True, none_ok=True)
    for key in ("student.onnx", "training.batched_terms", "metrics.sensitivity"):
        check_bool(cfg, key)
    for key in ("training.lever_rounds", "training.lever_image_size", "training.matmul_size",
                "training.lightning_rounds", "training.profile_top"):
        check_int(cfg, key, 1, none_ok=True)
    check_int(cfg, "training.lightning_steps", 0, none_ok=True, fix=" (0: no Lightning overhead table)")
    for key in ("training.levers", "training.profile_levers"):
        levers = get(cfg, key)
        if known_levers and levers is not MISSING and levers is not None:
            if isinstance(levers, str) or not isinstance(levers, list):
                raise ConfigError(f"{key}={levers!r} is not a list; use {key}=[{','.join(list(known_levers)[1:3])}]")
            unknown = sorted({str(x) for x in levers} - set(known_levers))
            if unknown:
                raise ConfigError(f"{key}: unknown {', '.join(unknown)}; use some of {', '.join(known_levers)}")
    page = get(cfg, "speed_page")
    if page is not MISSING and page is not None and not str(page).endswith(".md"):
        raise ConfigError(f"speed_page={page!r} is not a .md file; set speed_page=docs/results/speed.md or null")
