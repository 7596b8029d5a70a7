"""A run's MLflow parameters: the settings that describe the method, without bookkeeping or duplicates.

The composed config is flattened to ``cfg/<group>/<key>`` (the names ``spade.report``, the resume check and the
tests read: ``cfg/seed``, ``cfg/run_name``, ``cfg/model/size``, ``cfg/scale/name``) and then thinned by
:func:`run_params`:

- **kept**: the model's settings (size, learning rate, optimizer and schedule, the margin's formulation and its
  lambda, BCE weight), the data's (batch size, augmentation, validation fraction, target width, caps), the
  trainer's budget (epochs, steps, gradient clipping, precision, batches per epoch), the evaluation's thresholds
  (``cfg/metrics/...``), the recipe's and the scale's names, the scale's data sizes, the seed, the row's name and
  the metric that picks the best checkpoint; an optimizer or a schedule is named by its function
  (``cfg/model/optimizer=AdamW``).
- **dropped**: paths and checkpoints (the description names the prerequisites), Hydra, logger and callback
  internals, the closed-loop test's settings (``closed_loop``, ``drive/*``: how the model is driven, not trained), the run's tags (they are tags), ``task_name``, the sweep's ``seeds`` / ``rows``, threads,
  ``_target_`` / ``_partial_`` / ``_convert_`` markers, the trainer's bookkeeping (devices, progress bar,
  logging cadence), unset values (None, ``max_steps=-1``), and the copies: the recipe's and the scale's values
  (the model, data and trainer keys hold what the run used), the data generator's settings, the model's copy of
  ``metrics``.

The whole config stays in the run as the artifact ``config/train.yaml``. Lightning's own logging of the model's
hyperparameters (the same settings again, unprefixed: ``margin/lambda_dm`` beside ``cfg/model/margin/lambda_dm``)
is off: the modules save them with ``save_hyperparameters(logger=False)`` (the checkpoint keeps them).
"""

from __future__ import annotations

from fnmatch import fnmatchcase
from typing import Any

# flattened config keys (without the cfg/ prefix) left out of the params: fnmatch patterns ("*" crosses "/")
DROPPED = (
    "hydra*", "paths/*", "logger/*", "callbacks/*", "tags/*", "requires/*", "registry/*", "also_test*",
    "task_name", "seeds", "rows", "threads", "prerequisites", "ckpt_path", "train", "test", "test_untrained",
    "closed_loop", "drive/*",
    "recipe/*", "scale/*",
    "data/*_generate/*", "data/generator/*", "data/*_dir", "data/num_workers", "data/pin_memory",
    "data/persistent_workers", "data/eval_batch_size",
    "model/metrics/*", "model/grid_size", "model/val_metric_batches", "*_ckpt", "*/_partial_", "*/_convert_",
    "*/_recursive_", "_target_", "*/_target_",
    "trainer/accelerator", "trainer/devices", "trainer/num_nodes", "trainer/strategy*", "trainer/default_root_dir",
    "trainer/enable_*", "trainer/deterministic", "trainer/benchmark", "trainer/log_every_n_steps",
    "trainer/check_val_every_n_epoch", "trainer/num_sanity_val_steps", "trainer/limit_val_batches",
    "trainer/limit_test_batches", "trainer/sync_batchnorm", "trainer/use_distributed_sampler",
)
# ... except these (the recipe and the scale by name; the scale's data sizes)
KEPT = ("recipe/name", "scale/name", "scale/train_instances", "scale/test_instances", "scale/image_size",
        "scale/resolution_m")
UNSET = {("trainer/max_steps", -1)}  # a value that means "no setting" (the epochs bound the run)
NAMED_BY_TARGET = ("model/optimizer", "model/lr_scheduler")  # logged as the name of their function / class


def flatten(cfg: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """Nested dict -> {"a/b/c": value}; lists are kept as their string form (MLflow params are strings)."""
    out: dict[str, Any] = {}
    for key, value in cfg.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(flatten(value, f"{name}/"))
        else:
            out[name] = value
    return out


def kept(key: str) -> bool:
    """Whether flattened config key ``key`` (``model/optimizer/lr``) is a parameter of the run."""
    return key in KEPT or not any(fnmatchcase(key, pattern) for pattern in DROPPED)


def run_params(resolved: dict[str, Any]) -> dict[str, Any]:
    """The run's parameters (``cfg/<key>``: value) from its resolved config (see the module docstring)."""
    flat = flatten(resolved)
    params = {f"cfg/{k}": v for k, v in flat.items() if v is not None and kept(k) and (k, v) not in UNSET}
    for group in NAMED_BY_TARGET:
        target = flat.get(f"{group}/_target_")
        if target:
            params[f"cfg/{group}"] = str(target).rsplit(".", 1)[-1]
    return dict(sorted(params.items()))
