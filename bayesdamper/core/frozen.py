"""Frozen containers whose arrays stay read-only when pickled to another process.

NumPy unpickles every array writable. A window, record or input handed to a worker process would then give the
compiled kernels writable arrays where the parent process gives read-only ones, and numba types the two as different
arguments: every kernel the workers call would be compiled (and cached) a second time.
"""

from __future__ import annotations

import numpy as np

__all__ = ["ReadOnlyArrays", "frozen_copy", "readonly"]


def frozen_copy(a, dtype=np.float64) -> np.ndarray:
    """A read-only C-contiguous copy of ``a`` as ``dtype``: the data a frozen container stores, which no caller's
    array can change afterwards."""
    a = np.array(a, dtype=dtype, order="C")
    a.flags.writeable = False
    return a


def readonly(a, dtype=np.float64) -> np.ndarray:
    """``a`` as a C-contiguous read-only array of ``dtype``: ``a`` itself where it already is one, else a read-only
    view (of a converted copy where the dtype or layout differ)."""
    a = np.ascontiguousarray(a, dtype=dtype)
    if a.flags.writeable:
        a = a.view()
        a.flags.writeable = False
    return a


class ReadOnlyArrays:
    """Mixin of a frozen dataclass: its read-only array attributes are read-only again after unpickling."""

    def __getstate__(self) -> tuple[dict, tuple[str, ...]]:
        state = dict(self.__dict__)
        frozen = tuple(k for k, v in state.items() if isinstance(v, np.ndarray) and not v.flags.writeable)
        return state, frozen

    def __setstate__(self, state: tuple[dict, tuple[str, ...]]) -> None:
        values, frozen = state
        for k in frozen:
            values[k].flags.writeable = False
        self.__dict__.update(values)
