"""Pick/place decisions on a detected candidate (paper App. "Once the target object has been detected").

For a candidate target object g (or goal receptacle b) with uncertainty-weighted score Psi and
the score Psi' it would have after the best available view, assuming that view confirms the class:

- ``Psi >= tau``                               -> act on it (grasp / place there);
- ``Psi' >= min(tau, Psi + tau_inc)``          -> collect that view first;
- otherwise                                    -> leave it and go back to global search.

The second test accepts a view that could lift Psi over the threshold, and also one that would
raise it by at least tau_inc: a barely observed object has a low Psi because of its uncertainty,
and one more view is the cheapest way to find out.
"""

from __future__ import annotations

import enum


class Verdict(enum.Enum):
    ACT = "act"              # confident enough: grasp it / place on it
    LOOK = "look"            # another view is worth it
    IGNORE = "ignore"        # back to global search


def decide(psi: float, predicted_psi: float | None, tau: float, tau_increase: float) -> Verdict:
    """The paper's inequalities; ``predicted_psi`` None means no view is available (ignore)."""
    if psi >= tau:
        return Verdict.ACT
    if predicted_psi is not None and predicted_psi >= min(tau, psi + tau_increase):
        return Verdict.LOOK
    return Verdict.IGNORE
