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
    # The per-pose solve shares work with its own briefly-polling worker threads (not OpenMP,
    # whose idle threads would keep spinning against Blender's), so all cores pay off here.
    # MATDEFORM_THREADS=N (or OMP_NUM_THREADS) overrides the count; 1 runs serially.
    threads = (
        os.environ.get("MATDEFORM_THREADS")
        or os.environ.get("OMP_NUM_THREADS")
        or str(os.cpu_count() or 1)
    )
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


def available() -> bool:
    try:
        load()
    except ImportError:
        return False
    return True
