"""The sections of ``python -m spade.bench`` and the run that composes them (:func:`bench`).

``bench(cfg)`` takes the composed ``conf/bench.yaml`` and returns the results dict that
:func:`spade.perf.bench_report.format_report` prints and :func:`spade.perf.bench_report.write_json` writes. Importing this
module registers the ``${quick_or:QUICK,FULL}`` resolver the config uses.
"""

from __future__ import annotations

import logging
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from omegaconf import DictConfig, OmegaConf

from spade.perf.targets import check_targets
from spade.utils.timing import machine_info
from spade.perf.closed_loop import closed_loop_costs
from spade.perf.dataset import dataset_read_at_scale
from spade.perf.maps import procedural_map_costs, real_map_costs
from spade.perf.throughput import annotation_scaling, generation_throughput
from spade.utils.config import compose_config

log = logging.getLogger(__name__)

SECTIONS = ("student", "experts", "training", "metrics", "decoder", "data", "quality", "annotation_scaling",
            "annotation", "dataset", "maps", "contention", "closed_loop")
_KEYS = ("quick", "sections", "out_json", "work_dir", "expert_ckpt", "seed", "threads", *SECTIONS)


def _quick_or(quick_value: Any, full_value: Any, *, _root_: DictConfig) -> Any:
    """``${quick_or:QUICK,FULL}``: the first value when the config's ``quick`` is true, else the second."""
    return quick_value if _root_.get("quick") else full_value


OmegaConf.register_new_resolver("quick_or", _quick_or, replace=True)


def _plain(cfg: DictConfig, keys: tuple[str, ...]) -> dict[str, Any]:
    """The given keys of ``cfg`` resolved in place (interpolations may point elsewhere in the config), as plain data.

    Only these keys: the rest (``paths.output_dir``) may need a running Hydra app, and bench() works without."""
    return {k: OmegaConf.to_container(cfg[k], resolve=True) if OmegaConf.is_config(cfg[k]) else cfg[k]
            for k in keys if k in cfg}


def bench(cfg: DictConfig) -> dict[str, Any]:
    """Run the configured sections; returns the results (also what goes into the JSON file)."""
    c = _plain(cfg, _KEYS)
    sections = list(c.get("sections") or [])
    unknown = sorted(set(sections) - set(SECTIONS))
    if unknown:
        raise ValueError(f"unknown bench sections {unknown}; choose from {list(SECTIONS)}")
    if c.get("threads"):
        import torch

        torch.set_num_threads(int(c["threads"]))
    results: dict[str, Any] = {"mode": "quick" if c.get("quick") else "full", "machine": machine_info(),
                               "settings": {k: c.get(k) for k in sections}}
    temporary = c.get("work_dir") is None
    work = Path(tempfile.mkdtemp(prefix="spade_bench_")) if temporary else Path(c["work_dir"])
    work.mkdir(parents=True, exist_ok=True)
    try:
        if "student" in sections:
            results["student"] = _student(c["student"], work, c.get("threads"))
        if "experts" in sections:
            results["experts"] = _experts(c["experts"])
        if "training" in sections:
            results["training"], results["training_speed"] = _training(c["training"])
        if "metrics" in sections:
            results["metrics"] = _metrics(c["metrics"], c["seed"])
        if "decoder" in sections:
            from spade.perf.decoding import decoder_costs

            log.info("decoder: search vs skeleton per instance")
            results["decoder"] = decoder_costs(c["decoder"]["instances"], c["decoder"]["image_sizes"], c["seed"])
        datasets: dict[str, Any] = {}
        if "data" in sections or ("quality" in sections and not (c["quality"].get("test_dir") and c.get("expert_ckpt"))):
            datasets = _datasets(c["data"], work)
        if "data" in sections:
            from spade.perf.throughput import dataset_read_throughput

            log.info("data: reading %s", datasets["train_dir"])
            results["data"] = {"generation": datasets["generation"],
                               "read": dataset_read_throughput(datasets["train_dir"])}
        if "quality" in sections:
            results["quality"] = _quality(c["quality"], c.get("expert_ckpt"), datasets, work, c["seed"])
        if "annotation_scaling" in sections:
            results["annotation_scaling"] = _annotation_scaling(c["annotation_scaling"], work)
        if "annotation" in sections:
            results["annotation"] = _annotation(c["annotation"], work)
        if "dataset" in sections:
            results["dataset"] = _dataset(c["dataset"], work, c["seed"])
        if "maps" in sections:
            results["maps"] = _maps(c["maps"])
        if "closed_loop" in sections:
            results["closed_loop"] = _closed_loop(c["closed_loop"])
        if "contention" in sections:
            from spade.perf.contention import contention_table

            k = c["contention"]
            log.info("contention: solo and two concurrent training processes per thread setting")
            results["contention"] = {"size": k["size"], "rows": contention_table(
                [dict(s) for s in k["settings"]], k["size"], k["image_size"], k["batch_size"], k["seconds"])}
    finally:
        if temporary:
            shutil.rmtree(work, ignore_errors=True)
    results["targets"] = check_targets(results)
    return results


def _student(s: dict[str, Any], work: Path, threads: int | None) -> list[dict[str, Any]]:
    from spade.perf.student import student_latency

    rows = []
    for size in s["image_sizes"]:
        log.info("student latency at %d px: %s", size, s["sizes"])
        rows += student_latency(s["sizes"], size, s["batches"], s["runs"], onnx=s["onnx"],
                                threads=threads, workdir=work)
    return rows


def _experts(e: dict[str, Any]) -> list[dict[str, Any]]:
    from spade.perf.experts import expert_sampling_costs

    out = []
    for conditional, preset in ((True, e["cond_preset"]), (False, e["uncond_preset"])):
        if preset:
            log.info("expert sampling: %s expert %s at %d px", "cond" if conditional else "uncond", preset,
                     e["image_size"])
            out.append(expert_sampling_costs(conditional, preset, e["image_size"], e["ddim_steps"],
                                             e["max_timed_steps"], e["num_train_timesteps"]))
    return out


def _training(t: dict[str, Any]) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """The step table at every image size, then at ``lever_image_size``: each lever against the baseline, the
    profiles and Lightning's per-step overhead (spade/perf/training.py, spade/perf/lightning_overhead.py)."""
    from spade.perf.training import Setup, lever_table, step_profiles, training_step_times
    from spade.utils.hardware import describe

    matmul = {"matmul_size": t.get("matmul_size", 1024), "matmul_seconds": t.get("matmul_seconds", 0.5)}
    rows = []
    for size in t["image_sizes"]:
        log.info("training steps at %d px, batch %d", size, t["batch_size"])
        rows += training_step_times(t["student"], size, t["batch_size"], t["cond_presets"], t.get("uncond_preset"),
                                    t["runs"], t["warmup"], t.get("batched_terms", True),
                                    t.get("expert_presets") or (), **matmul)
    speed: dict[str, Any] = {"hardware": describe(), "matmul_size": matmul["matmul_size"]}
    px, batch = t.get("lever_image_size") or t["image_sizes"][0], t["batch_size"]
    cond = (t.get("cond_presets") or [None])[0]
    setups = [Setup("BC", t["student"])]
    if cond:
        setups.append(Setup("Cond-DBC", t["student"], cond))
    setups += [Setup("Expert", None, p) for p in (t.get("expert_presets") or ())[:1]]
    if t.get("levers"):
        log.info("training levers at %d px: %s", px, t["levers"])
        speed["levers"] = lever_table(setups, t["levers"], px, batch, t.get("lever_rounds", t["runs"]), t["warmup"],
                                      **matmul)
    if t.get("profile_levers"):
        log.info("training step profiles at %d px", px)
        speed["profiles"] = step_profiles(setups[:2], t["profile_levers"], px, batch, t.get("profile_top", 10))
    if t.get("lightning_steps"):
        from spade.perf.lightning_overhead import lightning_overhead

        log.info("Lightning's per-step overhead at %d px", px)
        speed["lightning"] = lightning_overhead(t["student"], px, batch, t["lightning_steps"],
                                                t.get("lightning_rounds", 1), t.get("lightning_settings") or [])
    instances, scenarios = t.get("evaluation_instances") or 0, t.get("drive_scenarios") or 0
    if instances or scenarios:
        from spade.perf.evaluation_cost import one_drive_cost, one_test_pass_cost

        log.info("evaluation cost at %d px: a test pass of %d instances, a drive of %d scenarios", px, instances,
                 scenarios)
        speed["evaluation"] = {
            "test_pass": one_test_pass_cost(t["student"], px, instances, batch) if instances else None,
            "drive": one_drive_cost(t["student"], scenarios, px) if scenarios else None}
    return rows, speed


def _metrics(m: dict[str, Any], seed: int) -> dict[str, Any]:
    from spade.perf.metrics import fid_sensitivity, metric_throughput

    log.info("metrics: APE + Hd19 and FID throughput")
    out = metric_throughput(m["instances"], m["image_size"], m["fid_images"], m.get("batch", 64), seed,
                            m.get("reference_instances", 0), m.get("loops_instances", 0))
    if m.get("sensitivity"):
        from spade.perf.metrics import shape_validity

        log.info("metrics: FID sensitivity")
        out["sensitivity"] = fid_sensitivity(m["sensitivity_images"], m["sensitivity_image_size"], seed)
        out["shape_validity"] = shape_validity(m["sensitivity_images"], m.get("shape_image_size", 64), seed)
    if m.get("fid_test_dir"):
        from spade.perf.metrics import fid_test_table

        log.info("metrics: FID table on %s", m["fid_test_dir"])
        out["fid_table"] = fid_test_table(m["fid_test_dir"], m.get("fid_resample_dir"), m.get("fid_shape", "L"))
    return out


def _annotation(a: dict[str, Any], work: Path) -> dict[str, Any]:
    """Each preset written by the annotation tool at its own size (or ``num_instances``), timed."""
    rows = []
    for preset in a["presets"]:
        out = work / "annotation" / preset
        shutil.rmtree(out, ignore_errors=True)
        log.info("annotation: preset %s", preset)
        rows.append(generation_throughput(out, preset, a.get("num_instances"), maps=a.get("maps"),
                                          workers=a.get("workers") or os.cpu_count() or 1))
        shutil.rmtree(out, ignore_errors=True)
    instances, seconds = sum(r["instances"] for r in rows), sum(r["seconds"] for r in rows)
    return {"maps": a.get("maps") or "the presets' procedural maps", "presets": rows, "instances": instances,
            "seconds": seconds, "instances_per_s": instances / seconds if seconds else 0.0}


def _annotation_scaling(a: dict[str, Any], work: Path) -> dict[str, Any]:
    """Annotation instances/s per worker on a set of few scenarios, per window size and worker count."""
    log.info("annotation scaling: preset %s, %d instances at %s px with %s workers", a["preset"],
             a["num_instances"], a["image_sizes"], a["workers"])
    rows = annotation_scaling(work, a["preset"], a["num_instances"], a["image_sizes"], a["workers"],
                              a.get("window_m", 6.4), a.get("maps"), a.get("spacing_m"), a.get("states_per_task"))
    return {"preset": a["preset"], "maps": a.get("maps") or "the preset's procedural map",
            "states_per_task": a.get("states_per_task"), "rows": rows}


def _dataset(d: dict[str, Any], work: Path, seed: int) -> dict[str, Any]:
    log.info("dataset: reading %s", d.get("path") or f"{d['instances']} synthetic instances")
    return dataset_read_at_scale(work, d["instances"], d["image_size"], d["waypoints"], d.get("path"), seed)


def _maps(m: dict[str, Any]) -> dict[str, Any]:
    maps_dir = m.get("dir")
    real = None
    if maps_dir and Path(maps_dir).expanduser().is_dir():
        log.info("maps: real maps in %s", maps_dir)
        real = real_map_costs(maps_dir, m["resolution_m"], m["robot_radius_m"], m.get("max_real"))
    log.info("maps: procedural, %d seeds", m["seeds"])
    return {"dir": maps_dir, "real": real, "procedural": procedural_map_costs(m["seeds"], m["robot_radius_m"])}


def _closed_loop(k: dict[str, Any]) -> dict[str, Any]:
    if not k.get("ckpt") or not k.get("dataset"):
        raise ValueError("the closed_loop section needs closed_loop.ckpt (a trained student) and closed_loop.dataset "
                         "(a scenario set, e.g. data/quickstart/test_scenarios100 from spade.evaluate closed_loop=true "
                         "drive.scenarios=100)")
    log.info("closed loop: %s on %s", k["ckpt"], k["dataset"])
    return closed_loop_costs(k["ckpt"], k["dataset"], k.get("scenarios"))


def _datasets(d: dict[str, Any], work: Path) -> dict[str, Any]:
    """An L-shape training set and a test set written with the annotation tool (timed: generation throughput)."""
    train_dir, test_dir = work / "data" / "lshape", work / "data" / "test"
    generation = []
    for root, preset, n, maps in ((train_dir, "lshape", d["train_instances"], d.get("maps")),
                                  (test_dir, "test", d["test_instances"], None)):
        if (root / "manifest.json").is_file():  # a kept work_dir: reuse, do not re-time
            continue
        log.info("data: annotating %d %s instances", n, preset)
        generation.append(generation_throughput(root, preset, n, d["window_px"], d["resolution_m"], maps,
                                                d.get("spacing_m"), d.get("workers", 1)))
    return {"train_dir": train_dir, "test_dir": test_dir, "generation": generation}


def _quality(q: dict[str, Any], expert_ckpt: str | None, datasets: dict[str, Any], work: Path,
             seed: int) -> dict[str, Any]:
    import torch
    from torch.utils.data import default_collate

    from spade.data.path_dataset import PathDataset
    from spade.perf.experts import sampler_quality

    if expert_ckpt:
        module, source = _load_expert(expert_ckpt), str(expert_ckpt)
    else:
        module = _train_expert(q, datasets, work, seed)
        source = (f"cond tiny, trained here {q['train_steps']} steps on {datasets['train_dir'].name} "
                  f"(T={q['num_train_timesteps']})")
    test_dir = Path(q["test_dir"]) if q.get("test_dir") else datasets["test_dir"]
    test = PathDataset(test_dir)
    trained = module.hparams.get("image_size")
    if trained is not None and tuple(test.image_size) != (trained, trained):
        raise ValueError(f"quality: the expert was trained on {trained} px windows, {test_dir} holds "
                         f"{test.image_size[0]} px ones: set quality.test_dir (or data.window_px) to match it")
    shapes = test.labels("shape")
    idx = [i for i, s in enumerate(shapes) if q.get("shape") in (None, s)]
    if not idx:
        raise ValueError(f"quality: no test instances of shape {q.get('shape')!r} in {test_dir}")
    chosen = np.unique(np.linspace(0, len(idx) - 1, min(q["samples"], len(idx))).round().astype(int))
    batch = default_collate([test[idx[i]] for i in chosen])
    batch = {k: v for k, v in batch.items() if isinstance(v, torch.Tensor)}
    steps = module.schedule.num_train_timesteps
    settings = [("ddim", int(k)) for k in q["ddim_steps"] if int(k) < steps] + [("ddpm", steps)]
    log.info("quality: %s on %d test instances", [f"{s}-{k}" for s, k in settings], len(chosen))
    module.eval()
    rows = sampler_quality(module, batch, settings, seed=seed)
    return {"expert": source, "test_dir": str(test_dir), "num_train_timesteps": steps, "rows": rows}


def _load_expert(path: str | Path) -> Any:
    from spade.models.modelfile import load_lightning, read_info
    from spade.training.expert_module import ExpertModule

    path = Path(path).expanduser()
    if not path.is_file():
        raise FileNotFoundError(f"expert_ckpt={path} does not exist; pass an expert checkpoint from "
                                "python -m spade.train +experiment=cond_expert_L, or leave it out to train a tiny one")
    role = read_info(path, checkpoint=True, required=False).get("role")
    if role != "expert":
        raise ValueError(f"expert_ckpt={path} has role {role!r}, not 'expert': pass a diffusion expert checkpoint")
    return load_lightning(ExpertModule, path)


def _train_expert(q: dict[str, Any], datasets: dict[str, Any], work: Path, seed: int) -> Any:
    """A tiny conditional expert trained on the bench's training set (``+experiment=cond_expert_L``)."""
    from spade.experiments.run import train

    out = work / "expert"
    overrides = [
        "+experiment=cond_expert_L", f"scale={q['train_scale']}", "model.preset=tiny", "logger=none",
        "callbacks=none", "test=false", f"seed={seed}", f"paths.output_dir={out}",
        f"data.train_dir={datasets['train_dir']}", f"data.test_dir={datasets['test_dir']}",
        "data.train_generate=null", "data.test_generate=null", f"trainer.max_steps={q['train_steps']}",
        "trainer.max_epochs=-1", "trainer.enable_progress_bar=false", "+trainer.enable_model_summary=false",
        "+trainer.limit_val_batches=0",
        f"model.num_train_timesteps={q['num_train_timesteps']}",
    ]
    log.info("quality: training a tiny conditional expert for %d steps", q["train_steps"])
    _, objects = train(compose_config("train", overrides))
    objects["trainer"].save_checkpoint(work / "expert.ckpt")
    return objects["model"]
