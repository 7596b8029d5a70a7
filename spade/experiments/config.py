"""``compose_config`` lives in :mod:`spade.utils.config` (the lowest floor, so that annotation, data and the
sketching app compose configs without importing the experiments package); this name stays for existing callers."""

from spade.utils.config import compose_config

__all__ = ["compose_config"]
