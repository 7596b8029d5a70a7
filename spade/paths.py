"""Where the project's own files are, and the ``${cwd:}`` config resolver (usable outside a Hydra app)."""

import os
from pathlib import Path

from omegaconf import OmegaConf

PROJECT_ROOT = Path(__file__).resolve().parents[1]
CONF_DIR = PROJECT_ROOT / "conf"

OmegaConf.register_new_resolver("cwd", os.getcwd, replace=True)
