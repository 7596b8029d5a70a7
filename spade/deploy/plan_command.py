"""What ``python -m spade.plan`` does: its command-line shorthands and one query from a composed config."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf

from spade.deploy.outputs import save_png
from spade.deploy.plan_picture import load_map, plan_image
from spade.deploy.plan_result import PlanResult
from spade.deploy.student_planner import Planner
from spade.annotation.sources import parse_procedural

__all__ = ["rewrite_argv", "run_plan"]

# Hydra options that take a separate value (``--cfg job``): that value is not a positional map.
_VALUE_FLAGS = {"--cfg", "-c", "--package", "-p", "--config-path", "-cp", "--config-name", "-cn",
                "--config-dir", "-cd", "--experimental-rerun"}
_POINT = re.compile(r"^(?P<key>\+?(?:start|goal))=(?P<value>[^\[\]'\"]+,[^\[\]'\"]+)$")


def rewrite_argv(args: list[str]) -> list[str]:
    """The command line as Hydra needs it: ``MAP.yaml`` -> ``map=MAP.yaml``, ``start=X,Y,YAW`` ->
    ``start=[X,Y,YAW]`` (Hydra would read a bare comma list as a sweep), ``model=PATH`` -> ``model_path=PATH``."""
    out: list[str] = []
    skip_next = False
    for arg in args:
        if skip_next:
            out.append(arg)
            skip_next = False
            continue
        if arg in _VALUE_FLAGS:
            skip_next = True
            out.append(arg)
            continue
        point = _POINT.match(arg)
        if arg.startswith("model="):  # `model` is a config group of conf/: the key is model_path
            out.append("model_path=" + arg[len("model="):])
        elif point:
            out.append(f"{point['key']}=[{point['value']}]")
        elif not arg.startswith("-") and "=" not in arg and _looks_like_map(arg):
            if any(a.startswith("map=") for a in args):
                raise SystemExit(f"spade.plan: got the map twice ({arg!r} and a map= argument); give one")
            out.append(f"map={arg}")
        else:
            out.append(arg)
    return out


def _looks_like_map(arg: str) -> bool:
    if arg.endswith((".yaml", ".yml")):
        return True
    try:
        return parse_procedural(arg) is not None
    except ValueError:  # a generator's kind with a bad seed (warehouse:abc): the map, refused by the config check
        return True


def run_plan(cfg: DictConfig) -> tuple[PlanResult, Path]:
    """Run the config's query (``conf/plan.yaml``); returns the result and the path of the picture written."""
    if cfg.get("model_path") in (None, ""):
        raise ValueError("no model: pass model=PATH (a student .ckpt from python -m spade.train or its .onnx "
                         "export) or set the SPADE_PLANNER_MODEL environment variable")
    options: dict[str, Any] = OmegaConf.to_container(cfg.planner, resolve=True)  # type: ignore[assignment]
    planner = Planner(cfg.model_path, device=cfg.device, **options)
    print(f"# model: {planner!r}", flush=True)  # its window and the robot footprint it was trained for
    m = load_map(cfg.map)
    result = planner.plan(m, list(cfg.start), list(cfg.goal))
    out = Path(cfg.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    pic = cfg.picture
    save_png(plan_image(m, result, float(pic.context_m), int(pic.width_px), bool(pic.probability)), out)
    return result, out
