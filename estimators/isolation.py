"""Isolation by structured residuals: a table of which residual components each fault can move
(its signature, e.g. ``estimators.cofd.fault_signatures``) and the components that fired point
to a fault hypothesis, or to none while more than one stays consistent (Sec. 3.2 of the COFD
paper: a residual crosses its threshold only for the faults it is sensitive to).

``signatures`` has shape (observers, components, groups), True where a fault of that group can
move that component; a hypothesis is a tuple of 0-based groups.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np


def hypothesis_signature(signatures: np.ndarray, hypothesis: Sequence[int]) -> np.ndarray:
    """The components a fault on every group of ``hypothesis`` (0-based) can move."""
    return np.asarray(signatures[:, :, list(hypothesis)].any(axis=2))


def isolate(fired: np.ndarray, signatures: np.ndarray, hypotheses: Iterable[Sequence[int]]) -> tuple[int, ...] | None:
    """The fault the fired components point to, or None.

    A hypothesis (a set of groups) is consistent when no fired component is one it cannot move
    (thresholds bound the fault-free residual, so an insensitive component stays below its
    threshold under that hypothesis). The answer is the unique minimal consistent hypothesis (no
    other consistent one that is not a superset of it); None when nothing fired, or when the
    consistent hypotheses leave a choice (not yet isolable, or a fault outside the hypotheses)."""
    isolation = Isolation(signatures, hypotheses)
    found = int(isolation(np.asarray(fired, dtype=bool)[None])[0])
    return None if found < 0 else isolation.hypotheses[found]


class Isolation:
    """``isolate`` for K runs at once, its tables made once: ``__call__`` takes the fired components
    of each run, shape (K, observers, components), and gives each run's answer as an index into
    ``hypotheses``, −1 for None."""

    def __init__(self, signatures: np.ndarray, hypotheses: Iterable[Sequence[int]]) -> None:
        self.hypotheses = [tuple(H) for H in hypotheses]
        self.silent = np.array([~hypothesis_signature(signatures, H).ravel() for H in self.hypotheses]).T.copy()
        """(components, hypotheses): True where the hypothesis cannot move the component."""
        self.smaller = np.array([[set(other) < set(H) for H in self.hypotheses] for other in self.hypotheses])
        """(other, H): True where ``other`` is a strict subset of H."""
        self.members = np.zeros((len(self.hypotheses) + 1, signatures.shape[2]), dtype=bool)
        """(hypotheses + 1, groups): each hypothesis's groups; the last row, for −1, none."""
        for i, H in enumerate(self.hypotheses):
            self.members[i, list(H)] = True

    def __call__(self, fired: np.ndarray) -> np.ndarray:
        fired = fired.reshape(len(fired), -1)
        if not fired.any():  # the usual tick
            return np.full(len(fired), -1)
        consistent = ~(fired @ self.silent)  # (K, hypotheses); a boolean product: any of the ands
        minimal = consistent & ~(consistent @ self.smaller)
        unique = (minimal.sum(axis=1) == 1) & fired.any(axis=1)
        return np.where(unique, minimal.argmax(axis=1), -1)


def unisolable(
    signatures: np.ndarray, hypotheses: Sequence[Sequence[int]]
) -> list[tuple[tuple[int, ...], tuple[int, ...]]]:
    """Pairs (H, H′) where a fault H that moves every component it can still leaves H′ consistent
    without H ⊂ H′: H can never be isolated from H′ by these observers. Empty for a good family."""
    clashes = []
    for H in hypotheses:
        sig = hypothesis_signature(signatures, H)
        for other in hypotheses:
            if (
                tuple(other) != tuple(H)
                and not set(H) < set(other)
                and not (sig & ~hypothesis_signature(signatures, other)).any()
            ):
                clashes.append((tuple(H), tuple(other)))
    return clashes
