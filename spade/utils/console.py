"""What SPADE's commands print: its own output, once, within :data:`CONSOLE_WIDTH` columns, not a library's
advertising or a library's second copy of its own lines."""

from __future__ import annotations

import contextlib
import logging
import re
import sys
import textwrap
import warnings
from typing import Iterator

__all__ = ["CONSOLE_WIDTH", "AdvertisingFilter", "ConsoleFormatter", "ConsoleHandler", "lightning_logs_once", "quiet_lightning_info",
           "quiet_library_deprecations", "quiet_third_party_advertising", "stage_progress_bar", "wrap"]

CONSOLE_WIDTH = 120
"""The widest line a command prints once its task has started: log records are wrapped to it
(:class:`ConsoleFormatter`), the closing summaries lay their lines out within it (:mod:`spade.tracking.summary`) and
the progress bar is cut to it. Only a word longer than the line (a long path, a URL) can pass it."""

# Lightning logs its product tips ("💡 Tip: ... try installing litlogger / litmodels") through this logger at INFO.
LIGHTNING_RANK_ZERO = "lightning.pytorch.utilities.rank_zero"


class AdvertisingFilter(logging.Filter):
    """Drops Lightning's product tips; every other record passes."""

    def filter(self, record: logging.LogRecord) -> bool:
        message = record.getMessage()
        return not (message.startswith("💡 Tip:") or "litlogger" in message or "litmodels" in message)


def quiet_third_party_advertising() -> None:
    """Install :class:`AdvertisingFilter` on Lightning's rank-zero logger (once; a record it drops reaches no
    handler, Lightning's own console handler included)."""
    logger = logging.getLogger(LIGHTNING_RANK_ZERO)
    if not any(isinstance(f, AdvertisingFilter) for f in logger.filters):
        logger.addFilter(AdvertisingFilter())


_NO_BREAK = "\u00a0"  # textwrap breaks at ASCII whitespace only
_FIGURE_AND_UNIT = re.compile(r"(?<=[\d>])(?:\d*) (?=%|cm\b|ms\b|px\b)")


def wrap(text: str, first: str = "", rest: str | None = None, width: int = CONSOLE_WIDTH) -> list[str]:
    """``text`` as lines of at most ``width`` characters: the first after ``first``, the others after ``rest``
    (``first``'s width in spaces by default). Words are never split (a path or a URL stays whole, to be pasted), nor
    a figure from its unit (``51 %``, ``>20 cm``)."""
    rest = " " * len(first) if rest is None else rest
    kept = _FIGURE_AND_UNIT.sub(lambda m: m.group(0)[:-1] + _NO_BREAK, text)
    lines = textwrap.wrap(kept, width, initial_indent=first, subsequent_indent=rest, break_long_words=False,
                          break_on_hyphens=False) or [first.rstrip()]
    return [line.replace(_NO_BREAK, " ") for line in lines]


class ConsoleFormatter(logging.Formatter):
    """The console's records (Hydra's console handler, ``conf/hydra/default.yaml``): the time, the level and the
    message, wrapped within :data:`CONSOLE_WIDTH`. The run's log file keeps Hydra's full format (date, logger name)
    on one line per record; Hydra's console format spent 50 to 75 characters on them before the message."""

    def __init__(self, fmt: str = "[%(asctime)s][%(levelname)s] %(message)s", datefmt: str = "%H:%M:%S") -> None:
        super().__init__(fmt, datefmt)

    def formatMessage(self, record: logging.LogRecord) -> str:  # noqa: N802 - logging's name
        text = super().formatMessage(record)
        indent = " " * (len(text) - len(record.message)) if text.endswith(record.message) else "    "
        return "\n".join(line for part in text.splitlines() or [""]
                         for line in (wrap(part, rest=indent) if len(part) > CONSOLE_WIDTH else [part]))


class ConsoleHandler(logging.StreamHandler):
    """The console's handler (Hydra's, ``conf/hydra/default.yaml``): a record logged while a progress bar is drawn
    gets a line of its own. Lightning logs "`Trainer.fit` stopped" at the end of the last epoch, before the bar's
    line ends; the record continued the bar's line (a line of about 200 characters). The bars are cleared before the
    record and drawn again after it (tqdm's ``external_write_mode``; stdout and stderr count as one console).

    A Lightning record that names the checkpoint its previous one named is left out of the console (the log file
    keeps it): testing a checkpoint, Lightning says "Restoring states from the checkpoint path at PATH", then
    "Loaded model weights from the checkpoint at PATH"; wrapped within 120 columns, both ended on the same line
    holding PATH alone."""

    _last_checkpoint: str | None = None

    def filter(self, record: logging.LogRecord) -> bool:  # type: ignore[override] # logging's signature varies
        if not super().filter(record):
            return False
        if not record.name.startswith("lightning"):
            return True
        message = record.getMessage()
        path = message.rsplit(" ", 1)[-1] if "checkpoint" in message else None
        repeated = path is not None and path == self._last_checkpoint
        self._last_checkpoint = path
        return not repeated

    def emit(self, record: logging.LogRecord) -> None:
        tqdm = sys.modules.get("tqdm")  # no bar without it: nothing to clear
        if tqdm is None:
            super().emit(record)
            return
        with tqdm.tqdm.external_write_mode(file=self.stream):
            super().emit(record)


LIGHTNING_LOGGERS = ("lightning", "lightning.pytorch", "lightning.fabric")
"""The loggers Lightning gives a console handler of its own at import."""


def lightning_logs_once() -> None:
    """Lightning's records reach the console once, through the root logger's handlers.

    ``import lightning`` gives its ``lightning`` logger a console handler of its own (``INFO: ...``) and lets its
    records propagate as well: under a Hydra job, whose root logger writes to the console and to the run's log file,
    every Lightning line was printed twice, plain and Hydra-formatted. Where the root logger has handlers (a
    command's task), Lightning's own console handlers are removed and its loggers propagate, so a record is printed
    once and kept in the log file; elsewhere (a library use, no logging set up) Lightning's handlers stay. Called
    where a command loads Lightning (after its import: the handler is added then)."""
    if not logging.getLogger().handlers:
        return
    for name in LIGHTNING_LOGGERS:
        logger = logging.getLogger(name)
        for handler in list(logger.handlers):
            if type(handler) is logging.StreamHandler:  # Lightning's own; a test's capture handler is a subclass
                logger.removeHandler(handler)
        logger.propagate = True


@contextlib.contextmanager
def quiet_lightning_info() -> Iterator[None]:
    """Lightning's rank-zero INFO lines left out within (its warnings still pass): a second trainer of one run (the
    untrained model's test) repeated the run's "GPU available ..." lines word for word."""
    logger = logging.getLogger(LIGHTNING_RANK_ZERO)
    level = logger.level
    logger.setLevel(max(level, logging.WARNING))
    try:
        yield
    finally:
        logger.setLevel(level)


LIBRARY_DEPRECATIONS = (
    # torch 2.13 deprecates LeafSpec, which Lightning 2.6's pytree helper still builds: printed at every fit and
    # test, twice per run; a library's note to itself, not the user's to act on
    (FutureWarning, r"`isinstance\(treespec, LeafSpec\)` is deprecated"),
    # under bf16-mixed (trainer=cpu's precision auto on a CPU with native bf16) Lightning's model summary says it
    # counts the parameters' bytes as fp32: true of the weights, which stay fp32; nothing to act on
    (UserWarning, r"Precision bf16-mixed is not supported by the model summary"),
)


def quiet_library_deprecations() -> None:
    """Ignore the deprecation warnings one library raises about another (:data:`LIBRARY_DEPRECATIONS`)."""
    for category, message in LIBRARY_DEPRECATIONS:
        warnings.filterwarnings("ignore", message=message, category=category)


def stage_progress_bar(enabled: bool = True, refresh_rate: int | None = None) -> object:
    """The console's progress: one line per stage (training, test), not a bar per validation loader.

    Lightning's ``TQDMProgressBar`` draws the training bar (one line, reset every epoch), a bar for the sanity
    check and a new one for every validation loader of every epoch: a run of a few epochs with three validation
    loaders scrolled hundreds of bar lines before its summary. This one keeps the training and test bars and draws no
    sanity-check or validation bar (the validation's figures still reach the training bar's postfix when it ends).
    ``refresh_rate``: batches between redraws (default 1 on a terminal, 25 when the output is a file or a pipe, where
    every redraw is a line). With ``enabled=False`` (``trainer.enable_progress_bar=false``: Lightning refuses a
    progress-bar callback then) a callback that does nothing. The bars are at most :data:`CONSOLE_WIDTH` wide (a
    file or a pipe has no width of its own: tqdm drew every redraw in full, its figures included) and their figures
    leave out the MLflow run's tag (``v_num``) and the training bar's ``train/`` prefix."""
    import sys

    from lightning.pytorch.callbacks import Callback, TQDMProgressBar
    from lightning.pytorch.callbacks.progress.tqdm_progress import Tqdm

    if not enabled:
        return Callback()

    class StageProgressBar(TQDMProgressBar):
        def init_sanity_tqdm(self) -> Tqdm:
            return Tqdm(disable=True)

        def init_validation_tqdm(self) -> Tqdm:
            return Tqdm(disable=True)

        def init_train_tqdm(self) -> Tqdm:
            return _narrow(super().init_train_tqdm())

        def init_test_tqdm(self) -> Tqdm:
            return _narrow(super().init_test_tqdm())

        def get_metrics(self, trainer, pl_module):  # type: ignore[no-untyped-def] # noqa: ANN001, ANN202
            items = super().get_metrics(trainer, pl_module)
            items.pop("v_num", None)
            return {k.removeprefix("train/"): v for k, v in items.items()}

    if refresh_rate is None:
        refresh_rate = 1 if sys.stdout.isatty() else 25
    return StageProgressBar(refresh_rate=refresh_rate)


def _narrow(bar: object) -> object:
    """``bar`` (a tqdm) drawn within :data:`CONSOLE_WIDTH` columns (a terminal's width where it is narrower)."""
    bar.ncols = min(getattr(bar, "ncols", None) or CONSOLE_WIDTH, CONSOLE_WIDTH)  # type: ignore[attr-defined]
    return bar
