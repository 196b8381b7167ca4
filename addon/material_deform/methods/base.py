"""What a method is (:class:`Method`, :class:`Result`) and the registry of methods.

Its own module, below every method module: the methods import it, and ``methods/__init__.py``
imports them, so no method imports the package that imports it.
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass

import numpy as np

from ..model import settings


@dataclass
class Result:
    """What :meth:`Method.solve` returns: positions (n_c,3) of the compacted mesh (float64, or
    float32 where the solver rounds for the key itself), and whether
    the solve is final. An iterative method that stopped on its per-update budget before it
    converged says ``done=False``; the session then keeps updating until it is."""

    positions: np.ndarray
    done: bool = True


class Method:
    """Interface of a method (the defaults suit a direct, non-iterative solver).

    Class attributes:
      key          enum identifier (never change it)
      number       enum value: Blender saves this integer in the .blend (never change it)
      label        shown in the Method menu (short: the panel shows it at the sidebar's
                   default width; tests/blender/test_ui.py checks that it fits)
      description  tooltip
      anchor_modes anchor modes this method understands (BindError for others)
      iterative    True: ``solve`` takes an iteration budget and warm-starts from ``state``
      settings_name / settings_class
                   the method's own PropertyGroup, registered as
                   ``obj.material_deform.<settings_name>`` (None: no settings of its own).
                   Settings the bind depends on go in ``fingerprint`` and get
                   ``update=updates.bind_setting``: the session then compares the object
                   with its bound state (changing a setting back makes the bind valid).
                   Live settings (read by ``check_live``) get ``update=updates.live_setting``
                   so that the current pose is solved again with them
    """

    key = ""
    number = -1
    label = ""
    description = ""
    anchor_modes = frozenset({"POSITION"})
    iterative = False
    settings_name: str | None = None
    settings_class = None

    def gather(self, obj, inputs, binding: bool) -> None:
        """Read and validate the method's own inputs into ``inputs.extra`` (and may set
        ``inputs.region``). Raise BindError with a message for the user; write nothing.
        ``binding``: Bind is gathering, so read what the bind freezes (e.g. an Empty's
        orientation) as it is now; otherwise read what the last bind stored."""

    def commit(self, obj, inputs) -> None:
        """Bind succeeded: store what ``gather(binding=True)`` froze on the object."""

    def fingerprint(self, obj, inputs) -> list:
        """Strings and arrays that, when they change, make the bind stale."""
        return []

    # what the fingerprint covers, as the stale message names it
    fingerprint_what = "method or its settings"

    def build(self, inputs):
        """Build and return the solver (all the heavy precomputation). Raise BindError."""
        raise NotImplementedError

    def solve(
        self,
        solver,
        transforms: np.ndarray,
        state: dict,
        budget: int | None,
        progress=None,
        rotations: np.ndarray | None = None,
    ) -> Result:
        """Positions for the anchor transforms (k,4,4), float64, each the motion of anchor a
        since bind in the mesh's local space. ``budget``: iterations for one live update, None
        to run to convergence (Settle, Bake). ``state`` is kept per object between calls.
        ``progress``: None or ``progress(fraction, text)``, which a long solve may call now and
        then (Settle's progress bar and status text). ``rotations``: (k,3) float64 rotation
        vectors (axis times angle, radians, any length), one per anchor, each a log of the
        rotation factor of its transform: the branch to blend, carrying the turns past half a
        turn (a 540-degree twist, not -180); None when every anchor turned by less than half a
        turn (the principal logs are then the branch). A method that blends or constrains
        rotations uses them; one that sees only positions may ignore them."""
        raise NotImplementedError

    def watched_objects(self, obj) -> tuple:
        """Objects besides the anchors' Empties whose placement this method reads (e.g. an
        Empty giving directions): the session keys live updates on their matrices too, so
        turning one re-runs ``check_live``, and an Empty listed here is owned by ``obj`` in
        the panel. None entries are skipped."""
        return ()

    def check_live(self, obj, entry, depsgraph) -> None:
        """Cheap per-update check of method inputs that can change without an edit the
        session sees (raise BindError to stop updating)."""

    def draw(self, layout, obj, entry) -> None:
        """The method's own settings, drawn below the common panel controls (in the Deform
        subpanel, at the sidebar's default width: short labels, a search field's label on a
        line of its own). ``entry``: the object's built solver and its state (``model.Entry``),
        None when there is none, for readouts of the last solve. The default draws every
        setting of ``settings_class`` that is not hidden, in the order declared."""
        group = self.settings_of(obj)
        if group is None:
            return
        for prop in group.bl_rna.properties:
            if prop.identifier != "rna_type" and not prop.is_hidden:
                layout.prop(group, prop.identifier)

    def settings_of(self, obj):
        """The object's group of this method's own settings, None if it has none."""
        return getattr(settings(obj), self.settings_name) if self.settings_name else None

    def live_budget(self, obj) -> int | None:
        """Iterations per live update (iterative methods), None to converge every update."""
        return None

    def status(self, state: dict) -> tuple[bool, str] | None:
        """(converged, text) about the last solve of an iterative method, e.g. the sweeps it
        took and its last move; Settle reports it and the panel shows it. None: nothing to say
        (direct methods)."""
        return None

    def seed(self, solver, state: dict, positions: np.ndarray) -> None:
        """An iterative method's warm start from positions (n_c,3) the output key already
        holds (after undo or reloading the file, when ``state`` is empty): the next live
        update continues from them instead of starting over."""


def convergence_status(state: dict, steps: str, hint: str) -> tuple[bool, str] | None:
    """:meth:`Method.status` of an iterative method whose state holds "spent" (steps of the
    pose), "move" (last move, fraction of the diagonal) and "converged", and optionally "error"
    (the estimated distance to the solution, fraction of the diagonal; infinite while unknown)."""
    if "converged" not in state:
        return None
    n = state["spent"]
    error = state.get("error")
    if error is None:
        how = f"last move {state['move']:.1e} of the diagonal"
    elif np.isfinite(error):
        how = f"estimated distance to the solution {error:.1e} of the diagonal"
    else:
        how = f"the moves are not shrinking yet, last move {state['move']:.1e} of the diagonal"
    if state["converged"]:
        return True, f"Converged: {n} {steps}, {how}"
    return False, f"Not converged after {n} {steps} ({how}): {hint}"


_methods: dict[str, Method] = {}


def register_method(method: Method) -> Method:
    taken = {m.number for m in _methods.values()}
    if not method.key or method.key in _methods or method.number < 0 or method.number in taken:
        raise ValueError(f"method {method.key!r}: key empty or taken, or number taken")
    params = inspect.signature(method.solve).parameters
    if "rotations" not in params and not any(p.kind == p.VAR_KEYWORD for p in params.values()):
        raise ValueError(
            f"method {method.key!r}: solve() must accept rotations=None (the anchors' rotation "
            "vectors, docs/methods.md)"
        )
    _methods[method.key] = method
    return method


def unregister_method(key: str) -> Method:
    """Take a method out of the registry (with the add-on unregistered: the Method menu and the
    settings groups are built from the registry when the add-on registers)."""
    return _methods.pop(key)


def get(key: str) -> Method:
    """The method for an enum key; unknown keys (a file from a newer version) raise KeyError."""
    return _methods[key]


def all_methods() -> list[Method]:
    return list(_methods.values())


def enum_items() -> list[tuple[str, str, str, int]]:
    """Items for the Method EnumProperty, in registration order, with their saved numbers."""
    return [(m.key, m.label, m.description, m.number) for m in _methods.values()]
