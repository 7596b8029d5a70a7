"""What SPADE's commands print: its own output, not a library's advertising."""

from __future__ import annotations

import logging

__all__ = ["AdvertisingFilter", "quiet_third_party_advertising", "stage_progress_bar"]

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


def stage_progress_bar(enabled: bool = True, refresh_rate: int | None = None) -> object:
    """The console's progress: one line per stage (training, test), not a bar per validation loader.

    Lightning's ``TQDMProgressBar`` draws the training bar (one line, reset every epoch), a bar for the sanity
    check and a new one for every validation loader of every epoch: a run of a few epochs with three validation
    loaders scrolled hundreds of bar lines before its summary. This one keeps the training and test bars and draws no
    sanity-check or validation bar (the validation's figures still reach the training bar's postfix when it ends).
    ``refresh_rate``: batches between redraws (default 1 on a terminal, 25 when the output is a file or a pipe, where
    every redraw is a line). With ``enabled=False`` (``trainer.enable_progress_bar=false``: Lightning refuses a
    progress-bar callback then) a callback that does nothing."""
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

    if refresh_rate is None:
        refresh_rate = 1 if sys.stdout.isatty() else 25
    return StageProgressBar(refresh_rate=refresh_rate)
