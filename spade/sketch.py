"""``python -m spade.sketch MAP.yaml [port=8770] [out_dir=...] [model=student.ckpt|.onnx] [annotate.KEY=VALUE]``:
sketching in the browser (spade/sketching/, README *Sketching in the browser*; settings in conf/sketch.yaml).

Before Hydra parses the command line, a leading positional map becomes ``map=...``, ``model=`` becomes
``model_path=`` and ``annotate.KEY=VALUE`` becomes ``++annotate.KEY=VALUE`` (conf/annotate.yaml overrides).
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import hydra
from omegaconf import DictConfig, OmegaConf

from spade.paths import CONFIG_PATH  # the configs (conf/ or the installed copy); registers the resolvers
from spade.utils.errors import run_entry_point, task
from spade.config.sketch_checks import validate_sketch_config

OmegaConf.register_new_resolver("sketch_dir", lambda m: re.sub(r"[^A-Za-z0-9_.-]+", "-", Path(str(m)).stem),
                                replace=True)


def rewrite_argv(args: list[str]) -> list[str]:
    out = []
    for arg in args:
        if arg.startswith("model="):
            arg = "model_path=" + arg[len("model="):]
        elif arg.startswith("annotate."):
            arg = "++" + arg
        elif "=" not in arg and not arg.startswith("-") and (out[-1:] != ["--cfg"]):
            arg = f"map={arg}"
        out.append(arg)
    return out


def _checked_app(cfg: DictConfig):  # noqa: ANN202
    """The config and inputs checked first (one ``error:`` line, exit 2), then the app and the options it serves
    with."""
    from spade.sketching import build_app

    options = validate_sketch_config(cfg)
    app = build_app(str(options.map), options.out_dir, options.annotate or {}, options.model_path, options.device,
                    hosts=[str(options.host), *(options.allowed_hosts or [])], models=options.models,
                    allow_unsigned=bool(options.allow_unsigned))
    return app, options


@hydra.main(version_base="1.3", config_path=CONFIG_PATH, config_name="sketch")
@task
def main(cfg: DictConfig) -> None:
    from spade.config.refusals import exit_on_user_error
    from spade.sketching import serve

    app, options = exit_on_user_error(_checked_app)(cfg)
    serve(app, options.host, int(options.port))


if __name__ == "__main__":
    sys.argv = [sys.argv[0], *rewrite_argv(sys.argv[1:])]
    run_entry_point(main)
