"""What a changed setting asks of the session: the ``update=`` callbacks of the saved settings.

The settings are declared below the session (``properties`` and each method's settings group;
the session reads them), so they cannot import it. The session hands in what it does about a
change instead, a :class:`Listener`, when the add-on registers (``handlers.register``), and
these callbacks pass each change on to it. Before that, and after unregister, a change asks
nothing: there is no bind to check then.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass


@dataclass(frozen=True)
class Listener:
    """The session's answers to a changed setting (each must never raise into Blender)."""

    # (obj, scene or None): a setting the bind depends on changed; drop the solver and compare
    # the object with its bound state again (changing it back makes the bind valid again)
    bind_setting_changed: Callable
    # (obj): a live setting changed; the next live update solves the current pose again
    live_setting_changed: Callable
    # (obj, scene): solve the current pose with the new live settings now and write it; a
    # failure becomes the object's stale reason
    solve_now: Callable


_listener: Listener | None = None


def connect(listener: Listener) -> None:
    global _listener
    _listener = listener


def disconnect() -> None:
    global _listener
    _listener = None


def bind_setting(self, context) -> None:
    """``update=`` of a setting the bind depends on (one the method's fingerprint covers)."""
    if _listener is not None:
        _listener.bind_setting_changed(self.id_data, getattr(context, "scene", None))


def live_setting(self, context) -> None:
    """``update=`` of a live setting: the next live update solves the pose again with it."""
    if _listener is not None:
        _listener.live_setting_changed(self.id_data)


def solve_now(obj, scene) -> None:
    """Solve the pose of ``obj`` with its new live settings now, for a setting whose effect
    should show at once (the caller checks that ``obj`` is bound, live and in Object Mode)."""
    if _listener is not None:
        _listener.solve_now(obj, scene)
