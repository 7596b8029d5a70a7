"""The typed loader options of :class:`~spade.data.datamodule.PathDataModule` (``data.*``), :class:`DataOptions`,
in the shape of :class:`spade.training.margin.MarginConfig`: ``__post_init__`` refuses a value of the wrong type
or out of range in one line naming the full config key, its value and the fix
(:class:`~spade.utils.errors.ConfigError`, a ``ValueError``).

The data module builds them from its constructor's arguments, and ``spade.train``'s preflight from the composed
config (:func:`spade.config.options.read_options`), so each check exists once, here. The data's folders and
generation settings are checked against the disk by :mod:`spade.config.dataset_checks`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from spade.data.encoding import MARKER_ENCODINGS
from spade.utils.errors import ConfigError
from spade.utils.option_checks import check_int_value, check_number_value, is_int

__all__ = ["DataOptions", "TARGET_SOURCES"]

TARGET_SOURCES: tuple[str, ...] = ("demonstration", "plausible_mean")
"""``data.target_source``: what BC learns, the demonstration drawn as the target, or the pixelwise mean of the
demonstration and its alternatives (:func:`spade.data.plausible.ceiling_map`, which needs a training set drawn with
alternatives)."""


@dataclass(frozen=True)
class DataOptions:
    """The loader options of :class:`~spade.data.datamodule.PathDataModule` (``data.*``). Defaults are the
    data module's."""

    node: ClassVar[str] = "data"

    batch_size: int = 32
    eval_batch_size: int | None = None
    num_workers: int = 0  # 0: load in the main process
    val_fraction: float = 0.1
    split_seed: int | None = 0
    max_train_instances: int | None = None
    max_test_instances: int | None = None
    target_width_px: int = 1  # the path target's width in pixels, odd
    encoding: str = "binary"  # the start and goal markers (spade.data.encoding.MARKER_ENCODINGS)
    target_source: str = "demonstration"  # BC's label: the demonstration, or plausible_mean (spade.data.plausible)
    max_unlabelled_instances: int | None = None
    unlabelled_teacher_samples: int = 4  # samples per state whose medoid labels it (spade.training.teacher_labels)

    def __post_init__(self) -> None:
        check_int_value("data.batch_size", self.batch_size, 1, fix=", e.g. data.batch_size=32")
        check_int_value("data.eval_batch_size", self.eval_batch_size, 1, none_ok=True)
        check_int_value("data.num_workers", self.num_workers, 0, fix=" (0 loads in the main process)")
        check_number_value("data.val_fraction", self.val_fraction, 0, 1, high_open=True,
                           fix=", e.g. data.val_fraction=0.15")
        check_int_value("data.split_seed", self.split_seed, none_ok=True)
        check_int_value("data.max_train_instances", self.max_train_instances, 1, none_ok=True)
        check_int_value("data.max_test_instances", self.max_test_instances, 1, none_ok=True)
        width = self.target_width_px
        if not is_int(width) or width < 1 or width % 2 == 0:
            raise ConfigError(f"data.target_width_px={width!r} is not an odd number of pixels >= 1; set it to 1 (or "
                              "3, 5, ...)")
        check_int_value("data.max_unlabelled_instances", self.max_unlabelled_instances, 1, none_ok=True)
        check_int_value("data.unlabelled_teacher_samples", self.unlabelled_teacher_samples, 1,
                        fix=" (4: the medoid of four samples)")
        if self.target_source not in TARGET_SOURCES:
            raise ConfigError(f"data.target_source={self.target_source!r} is not one of {list(TARGET_SOURCES)}; set "
                              "data.target_source=demonstration (the paper's BC) or plausible_mean (BC on the mean of "
                              "the demonstration and its alternatives)")
        if self.encoding not in MARKER_ENCODINGS:
            raise ConfigError(f"data.encoding={self.encoding!r} is not a marker encoding; use one of "
                              f"{list(MARKER_ENCODINGS)} (binary: the paper's discs)")
