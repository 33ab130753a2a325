"""The window of the last N ticks that the reconciliators' gain estimators work on (IJC 2018,
(50)–(53)), in preallocated arrays, for one run or for the K runs of a batch.

Each tick is written twice, at slot p and p + N of arrays twice as long as the window, so that the
window is always one contiguous slice of each array in time order: the estimators read it as an
(N, ·) array without copying or reordering it, and sum it in the same order every time. A batch's
window has a leading run axis, (K, 2N, ·): the runs append in lockstep, so they share the slots, and
each run's rows are the same contiguous (N, ·) slices its window alone would hold (``run``).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from typing import NamedTuple

import numpy as np


class Sample(NamedTuple):
    """One tick in the parameter estimator's window (of one run, or a row per run of a batch)."""

    y: np.ndarray
    """The readings the UIO used (a missing one replaced by its prediction)."""
    x_p: np.ndarray
    b: np.ndarray
    measured: np.ndarray
    """The readings as received (NaN where one did not arrive)."""
    u: np.ndarray
    """The known inputs and the affine term's 1, [u; 1], held from this tick to the next."""


class SampleWindow:
    """The last ``capacity`` samples, oldest first: appended one by one (the oldest drops out), read
    field by field as arrays (``field``), and rewritten in place (the gain test's replay). With
    ``runs`` = K, every field has a leading run axis: a sample is K rows, a field (K, ·, size)."""

    def __init__(self, capacity: int, sizes: tuple[int, int, int, int, int], runs: int | None = None) -> None:
        """``sizes``: the length of each field of a ``Sample``, in its order."""
        self.capacity = capacity
        lead = () if runs is None else (runs,)
        self.arrays = Sample(*(np.zeros((*lead, 2 * capacity, size)) for size in sizes))
        self.start = 0
        self.count = 0

    def __len__(self) -> int:
        return self.count

    def clear(self) -> None:
        self.start = self.count = 0

    def append(self, sample: Sample) -> None:
        if self.count < self.capacity:
            self.count += 1
        else:
            self.start = (self.start + 1) % self.capacity
        self[-1] = sample

    def extend(self, samples: Iterable[Sample]) -> None:
        for sample in samples:
            self.append(sample)

    def _slot(self, index: int) -> int:
        if not -self.count <= index < self.count:
            raise IndexError(f"sample {index} of a window of {self.count}")
        return (self.start + index % self.count) % self.capacity

    def __setitem__(self, index: int, sample: Sample) -> None:
        slot = self._slot(index)
        for array, value in zip(self.arrays, sample, strict=True):
            array[..., slot, :] = array[..., slot + self.capacity, :] = value

    def __getitem__(self, index: int) -> Sample:
        slot = self._slot(index)
        return Sample(*(array[..., slot, :].copy() for array in self.arrays))

    def __iter__(self) -> Iterator[Sample]:
        return (self[i] for i in range(self.count))

    def field(self, name: str, last: int | None = None) -> np.ndarray:
        """One field of the last ``last`` samples (all by default), oldest first, shape (·, size)
        (a batch's: (K, ·, size)): a view into the window, valid until the next change."""
        end = self.start + self.count
        return getattr(self.arrays, name)[..., end - (self.count if last is None else last) : end, :]

    def set_rows(self, index: int, rows: np.ndarray | slice, sample: Sample) -> None:
        """A batch's sample ``index`` rewritten for the runs ``rows`` only (each field (len(rows), size))."""
        slot = self._slot(index)
        for array, value in zip(self.arrays, sample, strict=True):
            array[rows, slot] = array[rows, slot + self.capacity] = value

    def run(self, r: int) -> SampleWindow:
        """Run r's window of a batch's: its arrays are views of the batch's rows, so what it writes
        the batch holds; its place in time (``start``, ``count``) is the batch's as of now."""
        window = SampleWindow.__new__(SampleWindow)
        window.capacity, window.start, window.count = self.capacity, self.start, self.count
        window.arrays = Sample(*(array[r] for array in self.arrays))
        return window
