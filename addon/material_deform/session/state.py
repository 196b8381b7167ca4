"""What the session keeps per object at run time, never saved: the built solvers (the cache),
why an object does not update (its stale reason), the mode it was last seen in, and which
objects' live results are still settling. Keyed by the object's pointer."""

from __future__ import annotations

from .. import bridge
from ..model import BindError, Entry, settings

_cache: dict[int, Entry] = {}


_stale: dict[int, str] = {}  # object pointer -> why it cannot update


_last_mode: dict[int, str] = {}


_unsettled: set[int] = set()  # objects whose last live solve stopped on its iteration budget


def stale_reason(obj) -> str:
    return _stale.get(obj.as_pointer(), "")


def cached_entry(obj) -> Entry | None:
    """The built solver of a bound object, None if there is none now (read-only use: a
    method's panel readout)."""
    return _cache.get(obj.as_pointer())


def record_failure(obj, reason: str) -> None:
    """Keep ``reason`` as why ``obj`` does not update (shown in the panel)."""
    _stale[obj.as_pointer()] = reason


def unsettled() -> bool:
    """True while some object's live result is still converging: the handlers then keep
    calling :func:`live_update` from a timer until every result has settled."""
    return bool(_unsettled)


def clear_cache() -> None:
    _cache.clear()
    _stale.clear()
    _last_mode.clear()
    _unsettled.clear()


def _stop(obj, reason: str) -> BindError:
    """Record why this object cannot update until it is bound again; returns the error."""
    key = obj.as_pointer()
    _stale[key] = reason
    _cache.pop(key, None)
    return BindError(reason)


def mark_stale(obj, reason: str) -> None:
    """Something the fingerprints do not cover changed (e.g. the axes Empty turned): stop
    updating until the next Bind. Settings the fingerprints cover call
    :func:`settings_changed` instead, so that changing them back makes the bind valid again."""
    s = settings(obj) if bridge.is_mesh(obj) else None
    if s is not None and s.bound:
        s.rebind_reason = reason  # saved, so it also holds after reloading the file
        key = obj.as_pointer()
        _stale[key] = reason
        _cache.pop(key, None)
