"""What SPADE's commands print: its own output, not a library's advertising."""

from __future__ import annotations

import logging

__all__ = ["AdvertisingFilter", "quiet_third_party_advertising"]

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
