"""Locate the ``matdeform`` core: the copy vendored inside the add-on (legacy zip) wins,
otherwise whatever is importable (Blender extension wheels, a dev install)."""

from __future__ import annotations

import os
import sys

_VENDOR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "_vendor")
_error: str | None = None


def load():
    """Return the matdeform module, or raise ImportError with an actionable message."""
    global _error
    if os.path.isdir(_VENDOR) and _VENDOR not in sys.path:
        sys.path.insert(0, _VENDOR)
    try:
        import matdeform
    except ImportError as exc:
        _error = f"matdeform core not available ({exc}); reinstall the add-on zip"
        raise ImportError(_error) from exc
    _error = None
    return matdeform


def available() -> bool:
    try:
        load()
    except ImportError:
        return False
    return True
