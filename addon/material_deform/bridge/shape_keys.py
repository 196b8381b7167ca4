"""Shape keys: the live output key (the hot path's write) and the record of what it holds,
the keys a bake writes with their keyframes, and the example keys read as arrays."""

from __future__ import annotations

import numpy as np

from ..errors import BindError
from .animation import fcurve_collection
from .arrays import _get, _raw_copy_into_key

OUTPUT_KEY = "Material Deform"


BAKE_PREFIX = "MD Bake "


POSE_RECORD = "material_deform_pose"  # custom property of the Key: what the output key holds


def absolute_shape_keys(obj) -> bool:
    """True if the mesh's shape keys are absolute (Relative unchecked): Blender then shows one
    key by the Evaluation Time, never a relative key over the Basis such as the output."""
    keys = obj.data.shape_keys
    return keys is not None and not keys.use_relative


def shape_key_info(obj) -> list[tuple[str, bool, bool]]:
    """(name, muted, is the reference key) of every shape key, in list order."""
    keys = obj.data.shape_keys
    if keys is None:
        return []
    ref = keys.reference_key
    return [(kb.name, bool(kb.mute), kb == ref) for kb in keys.key_blocks]


def shape_key_positions(obj, name) -> np.ndarray:
    """Absolute coordinates stored in a shape key (float64)."""
    kb = obj.data.shape_keys.key_blocks[name]
    return _get(kb.data, "co", len(kb.data), np.float32, 3).astype(np.float64)


def ensure_output_key(obj, name=OUTPUT_KEY):
    """Return (key_block, created_basis). Creates a Basis (copy of the mesh) if there were no
    shape keys, so the rest shape itself is never written to. Raises BindError if the key of
    that name is the reference key (the Basis was removed)."""
    created = False
    if obj.data.shape_keys is None:
        obj.shape_key_add(name="Basis", from_mix=False)
        created = True
    keys = obj.data.shape_keys
    kb = keys.key_blocks.get(name)
    if kb is not None and kb == keys.reference_key:
        raise BindError(
            f"Shape key '{name}' is the reference (Basis) key: rename it, or add a Basis above "
            "it, then Bind"
        )
    if kb is None:
        kb = obj.shape_key_add(name=name, from_mix=False)
        # keep edits going to the Basis, not to the output
        obj.active_shape_key_index = 0
    kb.value = 1.0
    kb.mute = False
    return kb, created


def output_key(obj, name=OUTPUT_KEY, pointer: int = 0):
    """The output key block: the one named ``name``, else the one at ``pointer`` (the block
    the session last wrote; found after a rename). None if neither exists."""
    keys = obj.data.shape_keys
    if keys is None:
        return None
    kb = keys.key_blocks.get(name)
    if kb is None and pointer:
        kb = next((k for k in keys.key_blocks if k.as_pointer() == pointer), None)
    return kb


def is_reference_key(obj, kb) -> bool:
    keys = obj.data.shape_keys
    return keys is not None and kb == keys.reference_key


def key_record(obj) -> str:
    """The record the session wrote with the output key ("" if none): saved in the .blend and
    restored by undo together with the key's coordinates."""
    keys = obj.data.shape_keys
    return "" if keys is None else str(keys.get(POSE_RECORD, ""))


def set_key_record(obj, text: str) -> None:
    keys = obj.data.shape_keys
    if keys is not None:
        keys[POSE_RECORD] = text


ROTATIONS = "material_deform_rotations"  # custom property of the Key: the vectors it shows


def key_rotations(obj, count: int) -> np.ndarray | None:
    """(count,3) rotation vectors the output key was last solved with (saved with it, restored
    by undo with it), None if there are none of that shape."""
    keys = obj.data.shape_keys
    got = None if keys is None else keys.get(ROTATIONS)
    if got is None:
        return None
    try:
        v = np.array(got[:], dtype=np.float64)
    except (TypeError, ValueError):
        return None
    if v.shape != (3 * count,) or not np.isfinite(v).all():
        return None
    return v.reshape(count, 3)


def set_key_rotations(obj, vectors) -> None:
    keys = obj.data.shape_keys
    if keys is not None:
        keys[ROTATIONS] = np.asarray(vectors, dtype=np.float64).ravel().tolist()


def write_key(obj, kb, positions) -> None:
    """Hot path: one bulk copy into the shape key, then the Key tagged for re-evaluation.

    ``KeyBlock.data.foreach_set`` goes item by item (~8 ms for 25k vertices), too slow for
    live use. Blender 4.1+ has ``KeyBlock.points`` with a bulk path; older versions get a
    memmove into the key's float[3] array after checking that it really is one contiguous
    block of the expected size, else the slow path.
    """
    flat = np.ascontiguousarray(positions, dtype=np.float32).ravel()
    points = getattr(kb, "points", None)
    if points is not None:
        points.foreach_set("co", flat)
    elif not _raw_copy_into_key(kb, flat):
        kb.data.foreach_set("co", flat)
    # The RNA update of the points: a copy-on-write tag of the Key alone, which re-evaluates the
    # geometry (the bulk write does the same itself from Blender 4.3 on; before, nothing does).
    # Not Key.update_tag(): that legacy tag also makes Blender flush visibility flags over the
    # whole depsgraph, +1 to +1.5 ms per update with 1000 other objects in the scene
    # (docs/performance.md, session 14). Also spares a copy-on-write of the whole mesh.
    kb.data.update()


def remove_output(obj, remove_basis: bool, name=OUTPUT_KEY, pointer: int = 0) -> None:
    kb = output_key(obj, name, pointer)
    if kb is not None and not is_reference_key(obj, kb):  # never the rest shape itself
        obj.shape_key_remove(kb)
    keys = obj.data.shape_keys
    if remove_basis and keys is not None and len(keys.key_blocks) == 1:
        # removing the last (reference) key writes its coordinates back to the mesh verbatim
        obj.shape_key_remove(keys.key_blocks[0])


def set_output_value(obj, value: float, name=OUTPUT_KEY) -> None:
    kb = output_key(obj, name)
    if kb is not None:
        kb.value = value


def bake_key(obj, frame, positions) -> str:
    name = f"{BAKE_PREFIX}{frame:04d}"
    keys = obj.data.shape_keys
    old = keys.key_blocks.get(name) if keys is not None else None
    if old is not None:
        obj.shape_key_remove(old)
    kb = obj.shape_key_add(name=name, from_mix=False)
    kb.data.foreach_set("co", np.asarray(positions, dtype=np.float32).ravel())
    for f, v in ((frame - 1, 0.0), (frame, 1.0), (frame + 1, 0.0)):
        kb.value = v
        kb.keyframe_insert("value", frame=f)
    obj.active_shape_key_index = 0
    return name


def bake_key_names(obj) -> list[str]:
    keys = obj.data.shape_keys
    if keys is None:
        return []
    return [kb.name for kb in keys.key_blocks if kb.name.startswith(BAKE_PREFIX)]


def remove_bake_keys(obj) -> int:
    """Remove the baked shape keys and their keyframes; returns how many keys went."""
    names = bake_key_names(obj)
    if not names:
        return 0
    keys = obj.data.shape_keys
    fcurves = fcurve_collection(keys.animation_data)
    if fcurves is not None:
        paths = {f'key_blocks["{n}"].value' for n in names}
        for fc in [fc for fc in fcurves if fc.data_path in paths]:
            fcurves.remove(fc)
        if len(fcurves) == 0:
            keys.animation_data.action = None  # nothing else animated: no empty action left
    for n in names:
        obj.shape_key_remove(keys.key_blocks[n])
    obj.active_shape_key_index = 0
    return len(names)
