"""``spade.bench``'s checks before any section runs."""

from __future__ import annotations

from collections.abc import Sequence

from omegaconf import DictConfig

from spade.experiments.checks.values import _MISSING, _check_bool, _check_int, _get
from spade.utils.errors import ConfigError


def validate_bench_config(cfg: DictConfig, known_sections: Sequence[str]) -> None:
    """``spade.bench``'s checks before any section runs: ``quick`` a boolean, ``sections`` among ``known_sections``
    (:data:`spade.perf.bench.SECTIONS`, passed in: the benchmark sits on a higher floor), a thread count."""
    _check_bool(cfg, "quick")
    sections = _get(cfg, "sections")
    if sections is not _MISSING and sections is not None:
        if isinstance(sections, str) or not isinstance(sections, list):
            raise ConfigError(f"sections={sections!r} is not a list; use sections=[{','.join(list(known_sections)[:2])}]")
        unknown = sorted({str(x) for x in sections} - set(known_sections))
        if unknown:
            raise ConfigError(f"sections: unknown {', '.join(unknown)}; use sections=[...] with some of "
                              f"{', '.join(known_sections)}")
    _check_int(cfg, "threads", 1, none_ok=True, fix=" (null: all cores)")
