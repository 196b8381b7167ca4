"""Locate the ``matdeform`` core: the copy vendored inside the add-on (legacy zip) wins,
otherwise whatever is importable (Blender extension wheels, a dev install)."""

from __future__ import annotations

import ctypes
import os
import sys

_VENDOR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "_vendor")
_error: str | None = None


def load():
    """Return the matdeform module, or raise ImportError with an actionable message."""
    global _error
    if os.path.isdir(_VENDOR) and _VENDOR not in sys.path:
        sys.path.insert(0, _VENDOR)
    # The core's OpenMP regions fight Blender's own worker threads: on a 2-core machine one
    # solve was ~8x slower with 2 OpenMP threads than with 1 (bench/bench_blender.py). Default
    # to 1 thread unless the user asked for more (MATDEFORM_THREADS or OMP_NUM_THREADS).
    threads = os.environ.get("MATDEFORM_THREADS") or os.environ.get("OMP_NUM_THREADS") or "1"
    os.environ.setdefault("OMP_NUM_THREADS", threads)
    try:
        import matdeform
    except ImportError as exc:
        _error = f"matdeform core not available ({exc}); reinstall the add-on zip"
        raise ImportError(_error) from exc
    _error = None
    _set_threads(matdeform, threads)
    return matdeform


_threads_set = False


def _set_threads(matdeform, threads: str) -> None:
    """OMP_NUM_THREADS is only read when the OpenMP runtime is first loaded, which may have
    happened before us, so also set the count through the core (or libgomp directly)."""
    global _threads_set
    if _threads_set:
        return
    _threads_set = True
    try:
        n = max(1, int(threads))
    except ValueError:
        n = 1
    if hasattr(matdeform, "set_num_threads"):
        matdeform.set_num_threads(n)
        return
    try:
        ctypes.CDLL("libgomp.so.1").omp_set_num_threads(n)
    except (OSError, AttributeError):
        pass  # no GNU OpenMP runtime (other platform or build): nothing to limit
