"""Thread sizing for training processes (spade/utils/threads.py)."""

from __future__ import annotations

import pytest
import torch

from spade.utils.errors import ConfigError
from spade.utils.threads import configure_threads, training_threads


def test_auto_threads_are_the_free_cores_and_at_least_one() -> None:
    assert training_threads(cores=2, busy=0.1) == 2
    assert training_threads(cores=2, busy=0.9) == 1   # another process keeps a core busy
    assert training_threads(cores=2, busy=3.7) == 1   # never fewer than one
    assert training_threads(cores=16, busy=5.2) == 11


def test_configure_threads_takes_a_count_auto_or_null(monkeypatch) -> None:
    before = torch.get_num_threads()
    try:
        assert configure_threads(1) == 1 and torch.get_num_threads() == 1
        assert configure_threads("2") == 2
        assert configure_threads(None) == 2  # torch's as it is
        monkeypatch.setenv("OMP_NUM_THREADS", "1")
        torch.set_num_threads(1)
        assert configure_threads("auto") == 1  # the user's OMP_NUM_THREADS wins over auto
        monkeypatch.delenv("OMP_NUM_THREADS")
        assert 1 <= configure_threads("auto") <= torch.get_num_threads() + 64
        for bad in (0, -1, "many", 1.5, True):
            with pytest.raises(ConfigError, match="is not a thread count"):
                configure_threads(bad)
    finally:
        torch.set_num_threads(before)
