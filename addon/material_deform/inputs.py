"""Reading and validating what a bind needs: the mesh, the anchors' faces, the stored
stiffness and the active method's own inputs, each checked with a message that says what to fix.

Raises BindError and touches nothing; the session decides what to do with the result (bind,
rebuild, or compare fingerprints for a full check).
"""

from __future__ import annotations

import numpy as np

from . import anchor_math as am
from . import bridge, methods, stiffness
from . import stiffness_map as sm
from .model import BindError, Inputs, load_core, settings
from .triangulation import flat_area


def method_of(obj) -> methods.Method:
    key = settings(obj).method
    try:
        return methods.get(key)
    except KeyError:
        raise BindError(f"Unknown method '{key}' (saved by a newer version?)") from None


def _check_mesh(a: bridge.MeshArrays) -> None:
    if not np.all(np.isfinite(a.rest)):
        raise BindError("Mesh has non-finite vertex coordinates")
    edge_use = np.bincount(a.loop_edge, minlength=len(a.edge_verts))
    if (edge_use > 2).any():
        raise BindError(
            f"Mesh is non-manifold: {int((edge_use > 2).sum())} edge(s) shared by more than two "
            "faces (Select > All by Trait > Non Manifold)"
        )
    degenerate = am.triangle_areas(a.rest, a.tris) <= flat_area(a.rest)
    if degenerate.any():
        polys = np.unique(a.tri_poly[degenerate])
        raise BindError(
            f"Mesh has {len(polys)} degenerate (zero-area) face(s), e.g. face {int(polys[0])}: "
            "use Mesh > Clean Up > Merge by Distance / Degenerate Dissolve"
        )


def _anchor_faces(obj, a: bridge.MeshArrays, method) -> tuple[list, list, list]:
    s = settings(obj)
    names = [anc.vertex_group for anc in s.anchors]
    weights = bridge.vertex_group_weights(obj, names)
    loop_poly = sm.loop_polygon_index(a.loop_start, a.loop_total)
    faces_out, modes, owner = [], [], np.full(len(a.tris), -1)
    for i, anc in enumerate(s.anchors):
        if anc.mode not in method.anchor_modes:
            raise BindError(
                f"Anchor '{anc.name}': mode '{anc.mode}' is not used by {method.label}; "
                "set it to Follow Empty"
            )
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
        faces_out.append(faces)
        modes.append(anc.mode)
    return faces_out, modes, names


def shared_mesh_message(obj, shared: list[str], then: str = "Bind") -> str:
    return (
        f"'{obj.name}' shares its mesh with '{shared[0]}' (a linked duplicate): the shape keys, "
        "and so the result, belong to the mesh and would show on both. Make it single-user "
        f"(Object > Relations > Make Single User > Object & Data), then {then}"
    )


def gather(obj, scene, binding: bool = False, build: bool = True) -> Inputs:
    """Read everything the solver needs and validate it; raises BindError with a clear
    message and touches nothing. ``binding``: called by Bind (the method may read the state
    it freezes now instead of what the last bind stored). ``build=False``: only what the
    fingerprints need (a full check of an unchanged bind skips the checks that passed at bind
    on this very data, which costs most of the time on large meshes)."""
    if not bridge.is_mesh(obj):
        raise BindError("Active object is not a mesh")
    why = bridge.not_editable(obj)
    if why:
        raise BindError(why)
    s = settings(obj)
    method = method_of(obj)
    mesh = obj.data
    if len(mesh.polygons) == 0:
        raise BindError("Mesh has no faces")
    shared = bridge.mesh_sharers(obj)
    if shared:
        raise BindError(shared_mesh_message(obj, shared))
    if bridge.absolute_shape_keys(obj):
        raise BindError(
            f"'{obj.name}' has absolute shape keys, which never show the result (a key relative "
            "to the Basis): check Relative in its Shape Keys panel, then Bind"
        )
    if len(s.anchors) == 0:
        raise BindError("No anchors: select faces in Edit Mode and click 'Add Anchor'")
    for anc in s.anchors:
        if not anc.vertex_group or not bridge.has_vertex_group(obj, anc.vertex_group):
            raise BindError(f"Anchor '{anc.name}': vertex group '{anc.vertex_group}' not found")
        if anc.empty is None:
            raise BindError(
                f"Anchor '{anc.name}' has no Empty (removed or never assigned): assign one in "
                "the Anchors list, then Bind"
            )
        if not bridge.object_in_scene(anc.empty, scene):
            raise BindError(f"Anchor '{anc.name}': Empty '{anc.empty.name}' is not in the scene")

    a = bridge.mesh_arrays(mesh)
    _check_mesh(a)
    anchor_faces, modes, names = _anchor_faces(obj, a, method)
    psi, phi = stiffness.stored_stiffness(obj, a)
    inp = Inputs(a, anchor_faces, modes, names, psi, phi)
    method.gather(obj, inp, binding)
    inp.fp = (
        am.fingerprint(a.tris, bridge.rest_positions_f32(mesh), a.tri_poly),
        am.fingerprint(*[x for a in zip(names, modes, anchor_faces, strict=True) for x in a]),
        am.fingerprint("uniform" if psi is None else psi, "default" if phi is None else phi),
        am.fingerprint(method.key, *method.fingerprint(obj, inp)),
    )
    if build:
        _check_components(inp)
        inp.used, inp.tris_c = am.compact(a.tris, len(a.rest))
    return inp


def _check_components(inp: Inputs) -> None:
    """Every face the solver moves must be in a part of the mesh that an anchor reaches."""
    a = inp.arrays
    comp, _ = load_core().face_components(a.tris)
    anchored = np.unique(comp[np.concatenate(inp.anchor_faces)])
    free = ~np.isin(comp, anchored)
    if inp.region is not None:  # only the region is solved: faces outside never move
        free &= np.isin(np.arange(len(a.tris)), inp.region)
    if free.any():
        raise BindError(
            f"{int(np.unique(a.tri_poly[free]).size)} face(s) are in a part of the mesh with no "
            "anchor: add an anchor there or separate that part"
        )
