"""One annotation run: a resolved config in, a dataset (and its preview) out, a summary back.

Sources, in order of precedence: ``sketches=`` (an operator's sketch file), ``rosbag.paths=`` (rosbag2
recordings), ``skipp.root=`` (SKIPP's published layout), else shape templates on ``maps=``. The command line is
:mod:`spade.annotate`; the sketching app and the benchmarks call :func:`annotate` directly, the data module
:func:`generate_dataset` (its generator, named by ``conf/data/generator/annotate.yaml``). The annotation config of a
data config's ``*_generate`` entry is :func:`spade.data.settings.annotation_config` (imported here too).
"""

from __future__ import annotations

import logging
import math
import time
from pathlib import Path
from typing import Any, Mapping

from omegaconf import DictConfig, OmegaConf
from tqdm import tqdm

from spade.annotation.pipeline import (
    RunStats,
    build_contexts,
    shapes_of,
    sketch_instances,
    template_instances,
    write_dataset,
)
from spade.annotation.preview import write_preview
from spade.annotation.scenarios import costmap_context
from spade.annotation.sources import load_map_sources
from spade.annotation.split import parse_split, split_record
from spade.data.settings import annotation_config, preset_override
from spade.annotation.importers.rosbag import rosbag_instances
from spade.annotation.importers.skipp import skipp_instances
from spade.annotation.sketch_file import load_sketch_file, sketch_to_pixels

log = logging.getLogger("spade.annotate")


def _plain(cfg: Mapping[str, Any] | DictConfig) -> dict[str, Any]:
    if isinstance(cfg, DictConfig):
        return OmegaConf.to_container(cfg, resolve=True)  # type: ignore[return-value]
    return dict(cfg)


def annotate(cfg: Mapping[str, Any] | DictConfig) -> dict[str, Any]:
    """Run the tool with a resolved config; returns a summary (instances, seconds, rates, rejections)."""
    cfg = _plain(cfg)
    cfg.pop("hydra", None)
    split = parse_split(cfg)  # a bad split= is refused before any map is loaded or any instance made
    out_dir = Path(cfg["out_dir"])
    res = float(cfg["window"]["resolution_m"])
    stats = RunStats()
    t0 = time.perf_counter()
    bar = tqdm(total=cfg.get("num_instances"), unit="inst", disable=not cfg.get("progress", True),
               desc=f"annotate -> {out_dir}")
    extra: dict[str, Any] = {"seed": int(cfg["seed"])}
    if cfg.get("sketches"):
        sketch_file = load_sketch_file(cfg["sketches"])
        source = load_map_sources([sketch_file.map], res)[0]
        ctx = costmap_context(source.map_id, source.map.grid, source.map.resolution, cfg, source.map.origin)
        sketches = [(s.name, s.shape, sketch_to_pixels(s, source.map)) for s in sketch_file.sketches]
        bar.total = None
        items = sketch_instances(ctx, sketches, cfg, stats, bar.update)
        extra.update(source="sketches", sketch_file=str(sketch_file.path), maps=[_map_info(source)])
    elif (cfg.get("rosbag") or {}).get("paths"):
        bar.total = None
        items = rosbag_instances(cfg, stats, bar.update)
        extra.update(source="rosbag")
    elif (cfg.get("skipp") or {}).get("root"):
        bar.total = None
        items = skipp_instances(cfg, stats, bar.update)
        res = float(cfg["skipp"]["resolution_m"]) * 256 / int(cfg["window"]["size_px"])
        extra.update(source="skipp")
    else:
        shapes_of(cfg)  # fail fast on an unknown shape, before loading maps
        sources = load_map_sources(cfg["maps"], res)
        contexts = build_contexts(sources, cfg)
        items = template_instances(contexts, cfg, stats, bar.update)
        extra.update(source="templates", maps=[_map_info(s) for s in sources])
        if split is not None:  # what the data checks read (spade.annotation.split.split_pair_problems)
            extra["split"] = split_record(split, [c.line for c in contexts])

    count = write_dataset(out_dir, items, cfg, lambda: {**extra, **stats.to_json()}, res)
    bar.close()
    seconds = time.perf_counter() - t0
    preview = None
    if cfg["preview"]["enabled"]:
        preview = write_preview(out_dir, int(cfg["preview"]["count"]), int(cfg["seed"]), int(cfg["preview"]["scale"]))
    summary = {
        "out_dir": str(out_dir),
        "instances": count,
        "seconds": round(seconds, 2),
        "instances_per_second": round(count / max(seconds, 1e-9), 1),
        "scenarios_accepted": len(stats.scenarios),
        "scenarios_tried": stats.scenarios_tried,
        "rejections": dict(sorted(stats.rejections.items())),
        "preview": str(preview) if preview else None,
    }
    warning = few_scenarios_warning(len(stats.scenarios), is_test_part(cfg, split, out_dir))
    if warning:
        summary["warning"] = warning
        log.warning("%s", warning)
    # the warning was logged on its own line just above: the summary's log line does not say it again
    log.info("annotation done: %s", {k: v for k, v in summary.items() if k != "warning"})
    return summary


FEW_SCENARIOS = 30  # a test part with fewer scenarios than this gets a warning in the summary


def is_test_part(cfg: Mapping[str, Any], split: Any, out_dir: Path) -> bool:
    """Whether this run writes a test set: ``split=<mode>:test``, the transfer preset's ``split=test``, or an
    output folder named as one (``.../test``, ``own_test``)."""
    if split is not None and getattr(split, "part", None) == "test":
        return True
    return cfg.get("split") == "test" or "test" in out_dir.name.lower()


def few_scenarios_warning(scenarios: int, test_part: bool) -> str | None:
    """The summary's warning for a test part of fewer than :data:`FEW_SCENARIOS` scenarios, with the uncertainty
    that implies: a scenario's instances are near-duplicates, so a share measured on the set (a failure rate, the
    share over 20 cm) is known to about +-1.96 * sqrt(0.25 / scenarios), the 95 % interval's half-width at 50 %."""
    if not test_part or scenarios <= 0 or scenarios >= FEW_SCENARIOS:
        return None
    half = 100 * 1.96 * math.sqrt(0.25 / scenarios)
    return (f"this test part has only {scenarios} scenarios: a share measured on it (a failure rate, the share "
            f"over 20 cm) is uncertain by up to about +-{half:.0f} percentage points (95 % interval), and two models "
            f"that differ by less cannot be told apart; draw more scenarios (more sketches or templates, a larger "
            f"split_fraction for the test part) for figures to compare (at least {FEW_SCENARIOS})")


def _map_info(source: Any) -> dict[str, Any]:
    m = source.map
    return {"map_id": source.map_id, "source": source.source, "size_px": [int(m.grid.shape[1]), int(m.grid.shape[0])],
            "resolution": m.resolution, "origin": list(m.origin)}


def alias_preset(argv: list[str]) -> list[str]:
    """``preset=X`` -> ``annotate/preset@_global_=X`` (the group lives under conf/annotate/ next to other tools')."""
    return [preset_override(a[len("preset="):]) if a.startswith("preset=") else a for a in argv]


def generate_dataset(root: Path, config: Any) -> None:
    """Build the dataset a data config's ``*_generate`` entry asks for at ``root`` (the data module's generator,
    ``conf/data/generator/annotate.yaml``, that ``prepare_data`` calls for a missing dataset)."""
    annotate(annotation_config(root, config))
