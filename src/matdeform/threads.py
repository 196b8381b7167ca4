"""Thread count of the core's parallel loops."""

from __future__ import annotations

from . import _core


def set_num_threads(n: int) -> None:
    """Use n >= 1 threads in the core's parallel loops (its task pool and OpenMP).

    Process-wide: every thread, also one started later, sees the new count.
    """
    if not isinstance(n, int) or n < 1:
        raise ValueError(f"n: expected an integer >= 1, got {n!r}")
    _core.set_num_threads(n)


def num_threads() -> int:
    """Threads the core's parallel loops use: the last set_num_threads, else OpenMP's default
    (OMP_NUM_THREADS or the core count; 1 when built without OpenMP)."""
    return _core.num_threads()
