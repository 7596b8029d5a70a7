"""Checks of a command's config before any MLflow run is opened or any data is generated: one module per command.

Each check raises :class:`~spade.utils.errors.ConfigError` (a :class:`~spade.utils.errors.UserError`) with one line
naming the key, its value and the fix; :func:`exit_on_user_error` turns a user error into that line on stderr and
exit status 2 at the entry points (``HYDRA_FULL_ERROR=1`` shows the traceback instead).

- :mod:`~spade.experiments.checks.train` (``spade.train``, called first thing) and
  :mod:`~spade.experiments.checks.evaluate` (``spade.evaluate``): wrong types and ranges, a window too small to
  hold a manoeuvre, a checkpoint of the wrong role (a student given as ``model.margin.expert_ckpt``) or of a window
  geometry other than the data's, and an existing dataset whose generation settings differ from the config's
  (:func:`spade.data.checks.check_dataset`, also run by the data module's ``prepare_data``, so a dataset is never
  silently reused for other settings);
- :mod:`~spade.experiments.checks.annotate`, :mod:`~spade.experiments.checks.export`,
  :mod:`~spade.experiments.checks.plan`, :mod:`~spade.experiments.checks.bench`,
  :mod:`~spade.experiments.checks.report`, :mod:`~spade.experiments.checks.sketch`,
  :mod:`~spade.experiments.checks.critic`: the other commands';
- what they share: :mod:`~spade.experiments.checks.values` (typed getters), :mod:`~spade.experiments.checks.data`,
  :mod:`~spade.experiments.checks.windows`, :mod:`~spade.experiments.checks.checkpoints`,
  :mod:`~spade.experiments.checks.files` (inputs, outputs, maps), :mod:`~spade.experiments.checks.store` (MLflow
  stores), and :mod:`~spade.experiments.checks.errors` (how an entry point reports a user error).
"""

from spade.experiments.checks.annotate import validate_annotate_config
from spade.experiments.checks.bench import validate_bench_config
from spade.experiments.checks.checkpoints import checkpoint_info, geometry_mismatch
from spade.experiments.checks.critic import validate_critic_config
from spade.experiments.checks.errors import ConfigError, UserError, exit_on_user_error, user_errors
from spade.experiments.checks.evaluate import validate_evaluate_config
from spade.experiments.checks.export import validate_export_config
from spade.experiments.checks.plan import validate_plan_config
from spade.experiments.checks.report import validate_report_config
from spade.experiments.checks.sketch import validate_sketch_config
from spade.experiments.checks.store import check_store_file
from spade.experiments.checks.train import RESUME_KEYS, validate_checkpoints, validate_train_config
from spade.experiments.checks.windows import check_window_holds_manoeuvre, model_downsampling

__all__ = [
    "RESUME_KEYS",
    "ConfigError",
    "UserError",
    "check_store_file",
    "check_window_holds_manoeuvre",
    "checkpoint_info",
    "exit_on_user_error",
    "geometry_mismatch",
    "model_downsampling",
    "user_errors",
    "validate_annotate_config",
    "validate_bench_config",
    "validate_checkpoints",
    "validate_critic_config",
    "validate_evaluate_config",
    "validate_export_config",
    "validate_plan_config",
    "validate_report_config",
    "validate_sketch_config",
    "validate_train_config",
]
