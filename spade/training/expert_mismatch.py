"""The error of an expert that does not fit its student, which the training modules share (kept here so that
``expert_module`` and ``student_module`` need not import each other)."""

from __future__ import annotations

from spade.utils.errors import UserError


class ExpertMismatchError(UserError, ValueError):
    """An expert for the diffusion margin that does not fit the student's data or the method (DBC / Cond-DBC)."""
