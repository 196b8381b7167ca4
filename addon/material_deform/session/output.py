"""The output shape key: the guards before a write (the rest shape is still the bound one, the
key is still there and not the Basis, every coordinate is finite) and the record saved with
the key, which says what pose and settings it holds and whether that result had settled."""

from __future__ import annotations

import hashlib

import numpy as np

from .. import bridge
from ..inputs import method_of
from ..model import BindError, Entry, settings
from .state import _stop, _unsettled


def _check_rest(obj, entry: Entry) -> None:
    """The live path's guard against a rest shape changed under the bind (Apply Scale, a
    script writing the Basis, vertices reordered): the Basis is compared with the bound rest
    bit for bit on every update (about 30 us at 25k vertices, docs/performance.md)."""
    buf = entry.extra.get("rest_buf")
    if buf is None:
        buf = entry.extra["rest_buf"] = np.empty_like(entry.rest_f32)
    if bridge.counts(obj.data) != entry.counts or not bridge.rest_unchanged(
        obj.data, entry.rest_f32, buf
    ):
        raise _stop(
            obj,
            "Rest shape changed since bind (Apply Scale, a script, or reordered vertices) - "
            "click Rebind",
        )


def _output_key(obj, entry: Entry):
    """The output key block, followed through a rename. Never the reference key."""
    s = settings(obj)
    kb = bridge.output_key(obj, s.output_key_name or bridge.OUTPUT_KEY, entry.key_pointer)
    if kb is None:
        raise _stop(
            obj,
            f"Output shape key '{s.output_key_name}' is gone (deleted or renamed before the "
            "file was saved): click Rebind to create it again",
        )
    if bridge.is_reference_key(obj, kb):
        raise _stop(
            obj,
            f"The Basis shape key was removed, so '{kb.name}' became the rest shape: undo "
            "(Ctrl+Z), or Reset and Bind again",
        )
    if kb.name != s.output_key_name:
        s.output_key_name = kb.name  # renamed by the user: keep writing to the same key
    entry.key_pointer = kb.as_pointer()
    return kb


def settings_signature(obj) -> bytes:
    """The method and the values of its own settings (what a live result depends on beyond
    the bind and the matrices)."""
    method = method_of(obj)
    vals: list = [method.key]
    group = getattr(settings(obj), method.settings_name) if method.settings_name else None
    if group is not None:
        for prop in group.bl_rna.properties:
            if prop.identifier == "rna_type":
                continue
            v = getattr(group, prop.identifier)
            if hasattr(v, "name"):  # an ID (an Empty)
                v = v.name
            elif hasattr(v, "__len__") and not isinstance(v, str):
                v = tuple(v)
            vals.append((prop.identifier, v))
    return repr(vals).encode()


def _record(obj, entry: Entry, mkey: bytes, settled: bool) -> str:
    """What the output key holds: a digest of the pose (the matrices) and the settings, and
    whether the result had settled. Saved with the key, so after undo or reloading the file
    the session knows whether the key already holds this pose."""
    sig = entry.extra.get("settings_sig")
    if sig is None:
        sig = entry.extra["settings_sig"] = settings_signature(obj)
    digest = hashlib.blake2b(mkey + b"|" + sig, digest_size=16).hexdigest()
    return f"{digest}:{int(settled)}"


_FLOAT32_MAX = float(np.finfo(np.float32).max)


def check_finite(obj, entry: Entry, x: np.ndarray) -> np.ndarray:
    """x as the contiguous float32 (n,3) array that keys and point caches store; BindError
    unless every coordinate of it is finite (a float64 beyond float32's range becomes inf).
    The method's state is dropped then: an iterative method must not continue from that
    iterate."""
    if x.dtype == np.float32:  # rounded by the solver already (errstate costs ~10 us)
        x32 = np.ascontiguousarray(x)
    else:
        with np.errstate(over="ignore", invalid="ignore"):
            x32 = np.ascontiguousarray(x, dtype=np.float32)
    flat = x32.reshape(-1)
    # Two reductions on the float32 copy the key write needs anyway (~10 us at 50k faces);
    # NaN propagates through both and fails the comparison. Not a dot product: numpy hands one
    # of 75k entries to OpenBLAS's threads, and OpenBLAS's worker then competes for the two
    # cores with the solver's task pool (the median 50k live update went from ~4 to ~2 ms).
    lo, hi = (float(flat.min()), float(flat.max())) if flat.size else (0.0, 0.0)
    if not (-_FLOAT32_MAX <= lo and hi <= _FLOAT32_MAX):
        entry.state.clear()
        _unsettled.discard(obj.as_pointer())
        raise BindError(
            f"Cannot pose '{obj.name}': the solver returned coordinates that are not finite "
            "(the shape key keeps its last result)"
        )
    return x32
