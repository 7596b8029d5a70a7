"""The config checks moved to :mod:`spade.experiments.checks` (a small module per command); import from there.

This module keeps the old import path working: every name it held, public (``from spade.experiments.checks import
*``) and private (the helpers some tests reach for), is re-exported unchanged.
"""

from spade.data.format import DatasetError  # noqa: F401 - was importable from here
from spade.experiments.checks import *  # noqa: F403 - every public name
from spade.experiments.checks import __all__ as _public
from spade.experiments.checks.checkpoints import (  # noqa: F401
    _a,
    _check_checkpoint,
    _check_geometry,
    _check_shipped,
    _geometry_text,
    _read_checkpoint,
)
from spade.experiments.checks.data import (  # noqa: F401
    _check_data,
    _check_datasets,
    _check_folder_path,
    _check_map_entries,
)
from spade.experiments.checks.files import (  # noqa: F401
    MODEL_SUFFIXES,
    _input_file,
    _map_files,
    _output_file,
    _point,
    _same_file,
)
from spade.experiments.checks.store import _check_logger_store, _store_path  # noqa: F401
from spade.experiments.checks.train import (  # noqa: F401
    _check_checkpoints,
    _check_expert_kind,
    _check_model,
    _check_resume,
    _check_trainer,
    _margin_config,
)
from spade.experiments.checks.values import (  # noqa: F401
    _MISSING,
    _check_bool,
    _check_choice,
    _check_int,
    _check_number,
    _dir,
    _get,
    _is_int,
    _is_number,
    _model_role,
    _opt,
    _range_text,
    _unset,
)
from spade.experiments.checks.windows import _check_window_size, _low  # noqa: F401

__all__ = [*_public, "DatasetError", "MODEL_SUFFIXES"]
