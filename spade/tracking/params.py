"""A run's MLflow parameters, logged by config group as lightning-hydra-template's ``log_hyperparameters`` does.

Each group of :data:`PARAM_GROUPS` is one node of the composed config, flattened to ``cfg/<group>/<key>`` (the names
``spade.report``, the resume check and the tests read: ``cfg/seed``, ``cfg/run_name``, ``cfg/model/size``,
``cfg/scale/name``):

- ``model``: the model's settings (size, learning rate, optimizer and schedule, each named by its function:
  ``cfg/model/optimizer=AdamW``; the margin's formulation and its lambda, BCE weight), less its copy of
  ``metrics`` and the grid and checkpoints it is handed;
- ``data``: batch size, augmentation, validation fraction, target width, caps, less paths, generators and loaders;
- ``trainer``: the training budget (epochs, steps, gradient clipping, precision, batches per epoch);
- ``metrics``: the evaluation's thresholds; ``recipe`` and ``scale`` by name (the scale's data sizes too);
- ``seed``, ``run_name`` and ``optimized_metric``, the metric that picks the best checkpoint.

A group not listed is no parameter: paths, Hydra, logger, callbacks, tags (they are tags), the closed-loop test's
``drive`` (how the model is driven, not trained), a sweep's ``seeds`` / ``rows``. Unset values (None,
``max_steps=-1``) and Hydra's ``_target_`` / ``_partial_`` markers are left out. A new option of a listed group
is a parameter without a line here.

The whole config stays in the run as the artifact ``config/train.yaml``. Lightning's own logging of the model's
hyperparameters (the same settings again, unprefixed: ``margin/lambda_dm`` beside ``cfg/model/margin/lambda_dm``)
is off: the modules save them with ``save_hyperparameters(logger=False)`` (the checkpoint keeps them).
"""

from __future__ import annotations

from dataclasses import dataclass
from fnmatch import fnmatchcase
from typing import Any


@dataclass(frozen=True)
class Group:
    """A config node logged as parameters: its keys (``only``, when given) less ``without`` (fnmatch patterns of
    the flattened key inside the node; ``*`` crosses ``/``)."""

    only: tuple[str, ...] | None = None
    without: tuple[str, ...] = ()

    def keeps(self, key: str) -> bool:
        if self.only is not None and key not in self.only:
            return False
        return not any(fnmatchcase(key, pattern) for pattern in self.without)


WHOLE = Group()
PARAM_GROUPS: dict[str, Group] = {
    "seed": WHOLE, "run_name": WHOLE, "optimized_metric": WHOLE,
    "recipe": Group(only=("name",)),
    "scale": Group(only=("name", "train_instances", "test_instances", "image_size", "resolution_m")),
    "model": Group(without=("metrics/*", "grid_size", "val_metric_batches", "*_ckpt")),
    "data": Group(without=("*_generate/*", "generator/*", "*_dir", "num_workers", "pin_memory", "persistent_workers",
                           "eval_batch_size")),
    "trainer": Group(only=("max_epochs", "min_epochs", "max_steps", "max_time", "precision", "channels_last",
                           "gradient_clip_val", "gradient_clip_algorithm", "accumulate_grad_batches",
                           "limit_train_batches")),
    "metrics": WHOLE,
}
MARKERS = ("_target_", "_partial_", "_convert_", "_recursive_")  # Hydra's, not settings
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
    group, _, inside = key.partition("/")
    chosen = PARAM_GROUPS.get(group)
    if chosen is None or key.rsplit("/", 1)[-1] in MARKERS:
        return False
    return not inside or chosen.keeps(inside)


def run_params(resolved: dict[str, Any]) -> dict[str, Any]:
    """The run's parameters (``cfg/<key>``: value) from its resolved config (see the module docstring)."""
    flat = flatten(resolved)
    params = {f"cfg/{k}": v for k, v in flat.items() if v is not None and kept(k) and (k, v) not in UNSET}
    for group in NAMED_BY_TARGET:
        target = flat.get(f"{group}/_target_")
        if target:
            params[f"cfg/{group}"] = str(target).rsplit(".", 1)[-1]
    return dict(sorted(params.items()))
