"""A training set of labelled and unlabelled states: the site's few demonstrations and the states of maps nobody
sketched, side by side in one loader.

A teacher can only teach what the student does not already see in its demonstrations: states of maps (or parts of
maps) without demonstrations. :class:`StateView` marks each instance ``labelled`` (its demonstration is a BC label)
or not (only the diffusion margin sees the state: :mod:`spade.training.margin`'s ``unlabelled`` option), and gives
every instance the same number of alternative slots, so that the two sets collate into one batch.
"""

from __future__ import annotations

import math

import torch
from torch.utils.data import Dataset

__all__ = ["StateView"]


class StateView(Dataset):
    """``dataset``'s instances with ``labelled`` (a bool tensor) and ``alternatives`` padded with NaN rows to
    ``alternatives`` slots (0: the key is left as the dataset gives it). ``num_waypoints`` sizes an empty slot for a
    dataset without alternatives."""

    def __init__(self, dataset: Dataset, labelled: bool, alternatives: int = 0, num_waypoints: int = 64) -> None:
        self.dataset, self.labelled = dataset, bool(labelled)
        self.alternatives, self.num_waypoints = int(alternatives), int(num_waypoints)

    def __len__(self) -> int:
        return len(self.dataset)  # type: ignore[arg-type]

    def __getitem__(self, index: int) -> dict:
        item = dict(self.dataset[index])
        item["labelled"] = torch.tensor(self.labelled)
        if self.alternatives > 0:
            alts = item.get("alternatives")
            k = int(item["waypoints"].shape[0]) if "waypoints" in item else self.num_waypoints
            padded = torch.full((self.alternatives, k, 2), math.nan, dtype=torch.float32)
            if alts is not None:
                if alts.shape[0] > self.alternatives:
                    raise ValueError(f"an instance has {alts.shape[0]} alternatives, more than the "
                                     f"{self.alternatives} slots of the combined training set")
                padded[: alts.shape[0]] = alts
            item["alternatives"] = padded
        return item
