"""What every method shares: anchors and their Empties, the solver cache, staleness, the live
update and the output shape key.

Talks to Blender only through ``bridge``. Built solvers live in a module-level cache (never
saved) keyed by object pointer and validated by fingerprints that are saved on the object. The
active method (``methods``) is asked to gather its own inputs, to build a solver and to solve
for the anchor transforms; the session never branches on which method it is.

The operators, the panel, the handlers and scripts use the names re-exported here. Inside, one
module per concept, each importing only those above it in this list:

- ``state``: what is kept per object at run time (cache, stale reasons, settling objects)
- ``pose``: the anchors' Empties, the bind pose and each anchor's motion since bind
- ``twist``: which branch of each anchor's rotation the methods blend (turns past half a turn)
- ``output``: the output shape key's guards and the record saved with it
- ``binding``: Bind, Rebind, Reset, and whether a bind still fits (fingerprints, undo, loading)
- ``live``: the live update, Update, Settle and the handler body

Underscore names are shared between these modules, never used outside the session.
"""

from __future__ import annotations

from ..inputs import gather, method_of
from ..model import BindError, Entry, Inputs, settings
from ..updates import Listener
from . import binding, live, output, pose, state, twist
from .binding import (
    after_undo,
    bind,
    entry_for,
    full_check,
    resolve_live,
    settings_changed,
    unbind,
)
from .live import apply, compute, live_update, settle, solve_now, solve_status
from .output import check_finite, settings_signature
from .pose import has_bind_pose, owner_of, place_new_anchor, reset_empties, transforms_now
from .state import (
    cached_entry,
    clear_cache,
    mark_stale,
    record_failure,
    stale_reason,
    unsettled,
)
from .twist import forget_changes, note_changes

# what a changed setting asks of the session (connected by handlers.register)
LISTENER = Listener(
    bind_setting_changed=settings_changed,
    live_setting_changed=resolve_live,
    solve_now=solve_now,
)

__all__ = [
    "BindError",
    "Entry",
    "Inputs",
    "LISTENER",
    "after_undo",
    "apply",
    "binding",
    "bind",
    "cached_entry",
    "check_finite",
    "clear_cache",
    "compute",
    "entry_for",
    "forget_changes",
    "full_check",
    "gather",
    "has_bind_pose",
    "live",
    "live_update",
    "mark_stale",
    "method_of",
    "note_changes",
    "output",
    "owner_of",
    "place_new_anchor",
    "pose",
    "record_failure",
    "reset_empties",
    "resolve_live",
    "settings",
    "settings_changed",
    "settings_signature",
    "settle",
    "solve_now",
    "solve_status",
    "stale_reason",
    "state",
    "transforms_now",
    "twist",
    "unbind",
    "unsettled",
]
