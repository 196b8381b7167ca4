"""Bind / update logic. Talks to Blender only through ``bridge``; keeps the built solvers in a
module-level cache (never saved) keyed by object pointer and validated by fingerprints that are
saved on the object."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from . import anchor_math as am
from . import bridge, core
from . import stiffness_map as sm


class BindError(Exception):
    """Bad input or stale bind; the message is meant for the user."""


@dataclass
class Inputs:
    arrays: bridge.MeshArrays
    anchor_faces: list  # per anchor: triangle indices
    modes: list
    shear: np.ndarray | None
    bend: np.ndarray | None
    used: np.ndarray | None  # vertices kept after dropping loose ones
    tris_c: np.ndarray
    fp: tuple
    region: np.ndarray | None = None  # triangles of the region of interest (paper Sec. 7)
    axes: np.ndarray | None = None  # anisotropy axes (3,3) when bend is (E,3)


@dataclass
class Entry:
    deformer: object
    fp: tuple
    counts: tuple
    rest: np.ndarray  # (n,3) float64, full vertex set
    used: np.ndarray | None
    use_4x4: bool
    n_anchors: int
    last_key: bytes | None = None
    extra: dict = field(default_factory=dict)


_cache: dict[int, Entry] = {}
_stale: dict[int, str] = {}  # object pointer -> why it cannot update
_last_mode: dict[int, str] = {}


def settings(obj):
    return obj.material_deform


def stale_reason(obj) -> str:
    return _stale.get(obj.as_pointer(), "")


def clear_cache() -> None:
    _cache.clear()
    _stale.clear()
    _last_mode.clear()


def after_undo(scene, objects) -> None:
    """Undo/redo loaded other saved data under the cache. Memfile undo keeps the objects'
    addresses, so cached solvers and stale verdicts would still be found but may belong to
    another state: drop the solvers of objects that are no longer bound, forget every verdict
    and re-check the bound objects of the scene against their mesh (as after the operators).
    Objects in Edit Mode are checked when they leave it (``live_update``)."""
    bound = {o.as_pointer() for o in objects if bridge.is_mesh(o) and settings(o).bound}
    for key in [k for k in _cache if k not in bound]:
        del _cache[key]
    _stale.clear()
    for obj in scene.objects:
        key = obj.as_pointer()
        if key not in bound:
            continue
        entry = _cache.get(key)
        if entry is not None:
            entry.last_key = None  # the output key was restored too: rewrite it on next update
        if obj.mode == "OBJECT":
            try:
                full_check(obj, scene)
            except Exception as exc:  # runs in a handler: never raise into Blender
                _stale[key] = f"Check failed: {exc}"
                _cache.pop(key, None)


def mark_stale(obj, reason: str) -> None:
    """Called when a bound setting changes in the UI: stop updating until the next Bind."""
    s = settings(obj) if bridge.is_mesh(obj) else None
    if s is not None and s.bound:
        s.rebind_reason = reason  # saved, so it also holds after reloading the file
        key = obj.as_pointer()
        _stale[key] = reason
        _cache.pop(key, None)


# --- stiffness ------------------------------------------------------------------------------


def stiffness_from_paint(obj) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Convert the painted group / colour attribute to per-face psi and per-edge phi and store
    them as mesh attributes. Returns (face paint, psi, phi)."""
    s = settings(obj)
    mesh = obj.data
    if s.anisotropic:
        from . import material_setup

        return material_setup.anisotropic_from_paint(obj)
    if len(mesh.polygons) == 0:
        raise BindError("Mesh has no faces")
    if s.stiffness_source == "VERTEX_GROUP":
        w = bridge.vertex_group_weights(obj, [s.stiffness_group]).get(s.stiffness_group)
        if w is None:
            raise BindError(
                f"No vertex group '{s.stiffness_group}': paint it in Weight Paint mode first"
            )
        vertex_paint = np.maximum(w, 0.0)  # vertices outside the group count as flexible
    else:
        rgba = bridge.color_attribute_vertex_rgba(mesh, s.color_attribute)
        if rgba is None:
            raise BindError(
                f"No color attribute '{s.color_attribute}': paint it in Vertex Paint mode first"
            )
        vertex_paint = sm.color_to_paint(rgba)
    a = bridge.mesh_arrays(mesh)
    loop_poly = sm.loop_polygon_index(a.loop_start, a.loop_total)
    face_paint = sm.face_paint_from_vertex(vertex_paint, a.loop_vert, loop_poly, a.n_polys)
    psi = sm.paint_to_stiffness(face_paint, s.stiffness_span)
    phi = sm.edge_stiffness(psi, a.loop_edge, loop_poly, len(a.edge_verts))
    bridge.write_float_attribute(mesh, bridge.SHEAR_ATTR, "FACE", psi)
    bridge.write_float_attribute(mesh, bridge.BEND_ATTR, "EDGE", phi)
    return face_paint, psi, phi


def show_stiffness(obj) -> np.ndarray:
    """Write a display colour attribute from the stored psi; returns the face paint values."""
    s = settings(obj)
    mesh = obj.data
    psi = bridge.read_float_attribute(mesh, bridge.SHEAR_ATTR, "FACE", len(mesh.polygons))
    if psi is None:
        raise BindError("No stiffness stored yet: run 'Stiffness from Paint' first")
    a = bridge.mesh_arrays(mesh)
    loop_poly = sm.loop_polygon_index(a.loop_start, a.loop_total)
    paint = sm.stiffness_to_paint(psi, s.stiffness_span)
    bridge.write_face_colors(mesh, bridge.DISPLAY_ATTR, sm.stiffness_colors(paint), loop_poly)
    return paint


# --- gathering and validating inputs ----------------------------------------------------------


def gather(obj, scene) -> Inputs:
    """Read everything the solver needs and validate it; raises BindError with a clear
    message and touches nothing."""
    if not bridge.is_mesh(obj):
        raise BindError("Active object is not a mesh")
    s = settings(obj)
    mesh = obj.data
    if len(mesh.polygons) == 0:
        raise BindError("Mesh has no faces")
    if len(s.anchors) == 0:
        raise BindError("No anchors: select faces in Edit Mode and click 'Add Anchor'")
    for anc in s.anchors:
        if not anc.vertex_group or not bridge.has_vertex_group(obj, anc.vertex_group):
            raise BindError(f"Anchor '{anc.name}': vertex group '{anc.vertex_group}' not found")
        if anc.empty is None:
            raise BindError(f"Anchor '{anc.name}' has no Empty assigned")
        if not bridge.object_in_scene(anc.empty, scene):
            raise BindError(f"Anchor '{anc.name}': Empty '{anc.empty.name}' is not in the scene")

    a = bridge.mesh_arrays(mesh)
    if not np.all(np.isfinite(a.rest)):
        raise BindError("Mesh has non-finite vertex coordinates")
    loop_poly = sm.loop_polygon_index(a.loop_start, a.loop_total)
    edge_use = np.bincount(a.loop_edge, minlength=len(a.edge_verts))
    if (edge_use > 2).any():
        raise BindError(
            f"Mesh is non-manifold: {int((edge_use > 2).sum())} edge(s) shared by more than two "
            "faces (Select > All by Trait > Non Manifold)"
        )
    areas = am.triangle_areas(a.rest, a.tris)
    diag = float(np.linalg.norm(a.rest.max(axis=0) - a.rest.min(axis=0)))
    degenerate = areas <= 1e-12 * max(diag, 1e-30) ** 2
    if degenerate.any():
        polys = np.unique(a.tri_poly[degenerate])
        raise BindError(
            f"Mesh has {len(polys)} degenerate (zero-area) face(s), e.g. face {int(polys[0])}: "
            "use Mesh > Clean Up > Merge by Distance / Degenerate Dissolve"
        )

    names = [anc.vertex_group for anc in s.anchors]
    weights = bridge.vertex_group_weights(obj, names)
    anchor_faces, modes, owner = [], [], np.full(len(a.tris), -1)
    for i, anc in enumerate(s.anchors):
        polys = am.anchor_polygons(
            weights[anc.vertex_group] >= 0, a.loop_vert, loop_poly, a.n_polys
        )
        faces = np.flatnonzero(polys[a.tri_poly]).astype(np.int64)
        if len(faces) == 0:
            raise BindError(
                f"Anchor '{anc.name}': vertex group '{anc.vertex_group}' contains no whole face"
            )
        if (owner[faces] >= 0).any():
            other = s.anchors[int(owner[faces][owner[faces] >= 0][0])].name
            raise BindError(f"Anchors '{other}' and '{anc.name}' share faces; make them disjoint")
        owner[faces] = i
        anchor_faces.append(faces)
        modes.append(anc.mode)

    from . import material_setup as ms  # anisotropy, region of interest (issue 4)

    region = ms.region_faces(obj, a)
    if region is not None:
        ms.check_anchors_in_region(region, anchor_faces, [anc.name for anc in s.anchors])
    md = _core()
    dual = np.asarray(md.dual_edges(a.tris), dtype=np.int64).reshape(-1, 2)
    comp, _ = md.face_components(a.tris)
    anchored = np.unique(comp[np.concatenate(anchor_faces)])
    free = ~np.isin(comp, anchored)
    if region is not None:  # only the region is solved: faces outside never move
        free &= np.isin(np.arange(len(a.tris)), region)
    if free.any():
        raise BindError(
            f"{int(np.unique(a.tri_poly[free]).size)} face(s) are in a part of the mesh with no "
            "anchor: add an anchor there or separate that part"
        )

    psi = bridge.read_float_attribute(mesh, bridge.SHEAR_ATTR, "FACE", a.n_polys)
    phi = bridge.read_float_attribute(mesh, bridge.BEND_ATTR, "EDGE", len(a.edge_verts))
    shear = bend = None
    if psi is not None:
        if not np.all(np.isfinite(psi)) or (psi <= 0).any():
            raise BindError("Stiffness attribute has values <= 0: run 'Stiffness from Paint'")
        shear = psi[a.tri_poly]
        if phi is not None:
            if not np.all(np.isfinite(phi)) or (phi <= 0).any():
                raise BindError("Bending attribute has values <= 0: run 'Stiffness from Paint'")
            bend = sm.dual_edge_bend(a.tris, dual, a.tri_poly, psi, a.edge_verts, phi)
    axes = None
    if s.anisotropic:
        bend = ms.anisotropic_bend(obj, a, dual)
        axes = ms.bound_axes(obj)

    used, tris_c = am.compact(a.tris, len(a.rest))
    fp = (
        am.fingerprint(a.tris, bridge.rest_positions_f32(mesh), a.tri_poly),
        am.fingerprint(
            *[x for f, m, n in zip(anchor_faces, modes, names, strict=True) for x in (n, m, f)],
            "whole mesh" if region is None else region,
        ),
        am.fingerprint(
            "uniform" if shear is None else shear,
            "default" if bend is None else bend,
            # integers: rounding floats could give -0.0 and 0.0 (different bytes)
            "local axes" if axes is None else np.rint(axes * 1e6).astype(np.int64),
        ),
    )
    return Inputs(a, anchor_faces, modes, shear, bend, used, tris_c, fp, region, axes)


def _core():
    try:
        return core.load()
    except ImportError as exc:
        raise BindError(str(exc)) from exc


def _build(inp: Inputs, mesh) -> Entry:
    md = _core()
    use_4x4, pinned = am.solve_plan(inp.modes, inp.anchor_faces, inp.arrays.tris)
    verts = inp.arrays.rest if inp.used is None else inp.arrays.rest[inp.used]
    if pinned is not None and inp.used is not None:
        remap = np.full(len(inp.arrays.rest), -1, dtype=np.int64)
        remap[inp.used] = np.arange(len(inp.used))
        pinned = remap[pinned]
    try:
        d = md.MaterialDeformer(
            verts,
            inp.tris_c,
            inp.anchor_faces,
            shear=inp.shear,
            bend=inp.bend,
            pinned=pinned,
            region=inp.region,
            axes=inp.axes,
        )
    except (ValueError, RuntimeError) as exc:
        raise BindError(f"Solver rejected the mesh: {exc}") from exc
    return Entry(
        deformer=d,
        fp=inp.fp,
        counts=bridge.counts(mesh),
        rest=inp.arrays.rest,
        used=inp.used,
        use_4x4=use_4x4,
        n_anchors=len(inp.anchor_faces),
        extra={"axes": inp.axes},
    )


def _stored_fp(obj) -> tuple:
    s = settings(obj)
    return s.fp_topology, s.fp_anchors, s.fp_stiffness


def _diff_reason(stored, current) -> str:
    what = ("mesh (topology or rest shape)", "anchors or region", "stiffness or axes")
    changed = [w for w, a, b in zip(what, stored, current, strict=True) if a != b]
    return "Changed since bind: " + ", ".join(changed) + " - click Bind again"


# --- public operations -------------------------------------------------------------------------


def bind(obj, scene, progress: Callable[[float, str], None] | None = None) -> Entry:
    progress = progress or (lambda _f, _t: None)
    progress(0.05, "Material Deform: reading mesh")
    from . import material_setup

    material_setup.store_bind_axes(obj)  # the axes Empty's orientation now
    inp = gather(obj, scene)
    progress(0.3, "Material Deform: factorizing (precompute)")
    entry = _build(inp, obj.data)
    progress(0.9, "Material Deform: writing shape key")
    s = settings(obj)
    for anc in s.anchors:
        anc.bind_matrix = bridge.world_matrix(anc.empty).ravel().tolist()
    s.fp_topology, s.fp_anchors, s.fp_stiffness = inp.fp
    had_keys = obj.data.shape_keys is not None
    kb, created = bridge.ensure_output_key(obj)
    if not s.bound or not had_keys:
        s.created_basis = created
    # a fresh bind starts at the rest shape exactly
    bridge.write_key(obj, kb, bridge.rest_positions_f32(obj.data))
    s.bound = True
    s.rebind_reason = ""
    key = obj.as_pointer()
    _cache[key] = entry
    _stale.pop(key, None)
    entry.last_key = _matrix_key(obj, None)
    progress(1.0, "")
    return entry


def unbind(obj) -> None:
    """Remove the output and forget the bind: the mesh is back to its rest shape bit for bit."""
    s = settings(obj)
    bridge.remove_output(obj, remove_basis=s.created_basis)
    s.bound = False
    s.rebind_reason = ""
    s.created_basis = False
    s.fp_topology = s.fp_anchors = s.fp_stiffness = ""
    key = obj.as_pointer()
    _cache.pop(key, None)
    _stale.pop(key, None)


def entry_for(obj, scene) -> Entry:
    """Cached solver for a bound object, rebuilt (e.g. after loading a .blend or undo) only if
    the saved fingerprint still matches. Raises BindError otherwise."""
    s = settings(obj)
    key = obj.as_pointer()
    if not s.bound:
        raise BindError("Not bound: click Bind")
    if s.rebind_reason:
        _stale[key] = s.rebind_reason
        _cache.pop(key, None)
        raise BindError(s.rebind_reason)
    entry = _cache.get(key)
    if (
        entry is not None
        and entry.fp == _stored_fp(obj)
        and entry.counts == bridge.counts(obj.data)
    ):
        return entry
    _cache.pop(key, None)
    if key in _stale and entry is None:
        raise BindError(_stale[key])
    try:
        inp = gather(obj, scene)
    except BindError as exc:
        _stale[key] = f"Cannot update: {exc}"
        raise BindError(_stale[key]) from exc
    if inp.fp != _stored_fp(obj):
        _stale[key] = _diff_reason(_stored_fp(obj), inp.fp)
        raise BindError(_stale[key])
    entry = _build(inp, obj.data)
    _cache[key] = entry
    _stale.pop(key, None)
    return entry


def full_check(obj, scene) -> str:
    """Re-read mesh, anchors and stiffness and compare to the bind; returns '' if unchanged."""
    key = obj.as_pointer()
    s = settings(obj)
    if not s.bound:
        return ""
    if s.rebind_reason:
        _stale[key] = s.rebind_reason
        return s.rebind_reason
    try:
        inp = gather(obj, scene)
    except BindError as exc:
        _stale[key] = f"Cannot update: {exc}"
        _cache.pop(key, None)
        return _stale[key]
    if inp.fp != _stored_fp(obj):
        _stale[key] = _diff_reason(_stored_fp(obj), inp.fp)
        _cache.pop(key, None)
        return _stale[key]
    _stale.pop(key, None)
    return ""


def _anchor_empties(obj, scene):
    s = settings(obj)
    out = []
    for anc in s.anchors:
        if anc.empty is None or not bridge.object_in_scene(anc.empty, scene):
            raise BindError(f"Anchor '{anc.name}': its Empty was removed - reassign it and Bind")
        out.append(anc)
    return out


def _matrix_key(obj, depsgraph, scene=None) -> bytes:
    mats = [bridge.world_matrix(obj, depsgraph)]
    for anc in settings(obj).anchors:
        if anc.empty is not None:
            mats.append(bridge.world_matrix(anc.empty, depsgraph))
    if settings(obj).axes_empty is not None:  # turning it after bind makes the bind stale
        mats.append(bridge.world_matrix(settings(obj).axes_empty, depsgraph))
    return b"".join(b"-" if m is None else m.tobytes() for m in mats)


def _check_axes(obj, entry, depsgraph) -> None:
    """Rebind is needed if the anisotropy axes moved since bind. The axes come from an SVD
    (LAPACK, which keeps an OpenBLAS thread spinning in bpy 4.x), so they are recomputed only
    when the object's or the axes Empty's matrix changed since the last check."""
    from . import material_setup

    emp = settings(obj).axes_empty
    mats = [bridge.world_matrix(o, depsgraph) for o in (obj, emp) if o is not None]
    key = b"".join(m.tobytes() for m in mats if m is not None)
    if entry.extra.get("axes_checked") == key:
        return
    now_axes = material_setup.axes(obj, depsgraph)
    if now_axes is None or not np.allclose(now_axes, entry.extra["axes"], atol=1e-6):
        mark_stale(obj, "Axes Empty changed since bind - click Bind again")
        raise BindError("Axes Empty changed since bind - click Bind again")
    entry.extra["axes_checked"] = key


def compute(obj, scene, depsgraph=None) -> np.ndarray:
    """Deformed positions (n,3) float64 for the current Empty transforms."""
    entry = entry_for(obj, scene)
    key = obj.as_pointer()
    if bridge.counts(obj.data) != entry.counts:
        _stale[key] = _diff_reason(_stored_fp(obj), ("?", *_stored_fp(obj)[1:]))
        _cache.pop(key, None)
        raise BindError(_stale[key])
    ancs = _anchor_empties(obj, scene)
    if entry.extra.get("axes") is not None:
        _check_axes(obj, entry, depsgraph)
    if len(ancs) != entry.n_anchors:
        raise BindError("Anchors changed since bind - click Bind again")
    mats = [bridge.world_matrix(a.empty, depsgraph) for a in ancs]
    for a, m in zip(ancs, mats, strict=True):
        if m is None:
            raise BindError(
                f"Anchor '{a.name}': Empty '{a.empty.name}' is not evaluated here "
                "(disabled in renders?)"
            )
    m_obj = bridge.world_matrix(obj, depsgraph)
    if m_obj is None:
        raise BindError("Object is not evaluated here")
    now = np.stack(mats)
    bind_m = np.array([tuple(a.bind_matrix) for a in ancs], dtype=np.float64).reshape(-1, 4, 4)
    if np.array_equal(now, bind_m):
        # the bind pose is the rest shape exactly, as Bind writes it (the solver would add
        # round-off): re-evaluating it after undo or reloading leaves the key as it was
        return entry.rest.copy()
    try:
        t = entry.extra.setdefault("pose", am.PoseTransforms())(m_obj, now, bind_m)
        x = entry.deformer.deform(t if entry.use_4x4 else np.ascontiguousarray(t[:, :3, :3]))
    except ValueError as exc:  # e.g. an Empty scaled to zero or mirrored (det <= 0)
        raise BindError(f"Cannot pose '{obj.name}': {exc}") from None
    if entry.used is None:
        return x
    out = entry.rest.copy()
    out[entry.used] = x
    return out


def apply(obj, scene, depsgraph=None, force: bool = False) -> bool:
    """Write the deformation into the output shape key if any driver moved. True if written."""
    entry = entry_for(obj, scene)
    mkey = _matrix_key(obj, depsgraph)
    kb = bridge.output_key(obj)
    if not force and kb is not None and mkey == entry.last_key:
        return False
    x = compute(obj, scene, depsgraph)
    if kb is None:
        kb, _ = bridge.ensure_output_key(obj)
    bridge.write_key(obj, kb, x)
    entry.last_key = mkey
    return True


def live_update(scene, depsgraph=None) -> None:
    """Handler body: update every bound, live object of the scene. Errors are recorded as
    stale reasons (shown in the panel), never raised into Blender."""
    for obj in scene.objects:
        if obj.type != "MESH":
            continue
        s = settings(obj)
        if not (s.bound and s.live):
            continue
        key = obj.as_pointer()
        mode, prev = obj.mode, _last_mode.get(key, "OBJECT")
        _last_mode[key] = mode
        if mode != "OBJECT":
            continue  # never fight Edit/Paint modes
        if prev != "OBJECT" and full_check(obj, scene):
            continue
        try:
            apply(obj, scene, depsgraph)
        except Exception as exc:  # a handler must never take Blender down
            msg = str(exc) if isinstance(exc, BindError) else f"Update failed: {exc}"
            if _stale.get(key) != msg:
                print(f"Material Deform: '{obj.name}' not updated: {msg}")  # background runs
            _stale[key] = msg


def prepare_scene(scene) -> None:
    """Build the solvers of all bound objects (after loading a file), recording stale ones."""
    for obj in scene.objects:
        if obj.type == "MESH" and settings(obj).bound:
            try:
                entry_for(obj, scene)
            except BindError:
                pass  # reason is kept in _stale and shown in the panel
            except Exception as exc:  # never break file loading
                _stale[obj.as_pointer()] = f"Rebuild failed: {exc}"


def bake(obj, scene, frames, progress=None) -> list[str]:
    """Write one keyframed shape key per frame; turns Live off and mutes the live output."""
    progress = progress or (lambda _f, _t: None)
    entry_for(obj, scene)
    s = settings(obj)
    names = []
    frames = list(frames)
    old = scene.frame_current
    s.live = False
    try:
        for i, f in enumerate(frames):
            bridge.frame_set(scene, f)
            dg = bridge.evaluated_depsgraph_from_scene(scene)
            names.append(bridge.bake_key(obj, f, compute(obj, scene, dg)))
            progress((i + 1) / len(frames), f"Material Deform: baking frame {f}")
    finally:
        bridge.frame_set(scene, old)
    bridge.set_output_value(obj, 0.0)
    return names
