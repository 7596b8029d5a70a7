"""The SPADE paper's parameter counts, torch-free: what the presets are checked against and the tables print.

:mod:`spade.models.student` sizes its presets to these counts (a test holds them within 3 %); ``spade.report``'s
tables show them beside the measured counts without importing torch.
"""

PAPER_PARAMETER_COUNTS: dict[str, int] = {"small": 117_025, "medium": 1_926_209, "large": 31_114_785}
"""Trainable parameter counts of the SPADE paper's students (3 input channels, 1 output)."""

PAPER_COND_EXPERT_PARAMETERS = 9_218_561
"""Trainable parameters of the paper's FiLM-conditioned expert at 64 px."""
