"""Issue 4 on the Blender side: anisotropic bending stiffness (paper Sec. 5), the region of
interest (Sec. 7) and learning stiffness from shape keys (Sec. 6).

Same layer as ``session``: reads and writes Blender data only through ``bridge``, numpy maths
in ``aniso_map`` / ``stiffness_map``, the solver via ``core``. Errors are ``BindError``.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from . import anchor_math as am
from . import aniso_map as amap
from . import bridge, core
from . import stiffness_map as sm
from .session import BindError  # session imports this module lazily (no import cycle)


def _settings(obj):
    return obj.material_deform


def _loop_poly(a: bridge.MeshArrays) -> np.ndarray:
    return sm.loop_polygon_index(a.loop_start, a.loop_total)


# --- anisotropic paint -------------------------------------------------------------------------


def axis_vertex_paint(obj) -> np.ndarray:
    """(n,3) paint per vertex and axis: the groups '<group> X/Y/Z' or the colour's R, G, B."""
    s = _settings(obj)
    if s.stiffness_source == "VERTEX_GROUP":
        names = amap.axis_group_names(s.stiffness_group)
        w = bridge.vertex_group_weights(obj, names)
        missing = [n for n in names if n not in w]
        if missing:
            raise BindError(
                "Anisotropic: no vertex group "
                + ", ".join(f"'{n}'" for n in missing)
                + ": paint one group per rotation axis in Weight Paint mode"
            )
        return np.stack([np.maximum(w[n], 0.0) for n in names], axis=1)
    rgba = bridge.color_attribute_vertex_rgba(obj.data, s.color_attribute)
    if rgba is None:
        raise BindError(
            f"No color attribute '{s.color_attribute}': paint it in Vertex Paint mode first"
        )
    return np.clip(rgba[:, :3], 0.0, 1.0)


def anisotropic_from_paint(obj):
    """Per-axis paint -> per-edge bending stiffness (e,3) in ``md_bend_stiffness_xyz``, plus
    the scalar attributes: shear psi from the plain group (or the mean of the colour channels /
    of the three axes when that group does not exist) and ``md_bend_stiffness`` = mean of psi of
    the adjacent faces as in the isotropic case. Returns (face paint (P,3), psi, phi3)."""
    s = _settings(obj)
    mesh = obj.data
    if len(mesh.polygons) == 0:
        raise BindError("Mesh has no faces")
    vp3 = axis_vertex_paint(obj)
    a = bridge.mesh_arrays(mesh)
    lp = _loop_poly(a)
    fp3 = amap.per_axis_face_paint(vp3, a.loop_vert, lp, a.n_polys)
    shear_vp = None
    if s.stiffness_source == "VERTEX_GROUP":
        w = bridge.vertex_group_weights(obj, [s.stiffness_group]).get(s.stiffness_group)
        shear_vp = None if w is None else np.maximum(w, 0.0)
    if shear_vp is None:
        shear_fp = fp3.mean(axis=1)
    else:
        shear_fp = sm.face_paint_from_vertex(shear_vp, a.loop_vert, lp, a.n_polys)
    span = s.stiffness_span
    psi = sm.paint_to_stiffness(shear_fp, span)
    phi = sm.edge_stiffness(psi, a.loop_edge, lp, len(a.edge_verts))
    phi3 = amap.per_axis_edge_stiffness(
        sm.paint_to_stiffness(fp3, span), a.loop_edge, lp, len(a.edge_verts)
    )
    bridge.write_float_attribute(mesh, bridge.SHEAR_ATTR, "FACE", psi)
    bridge.write_float_attribute(mesh, bridge.BEND_ATTR, "EDGE", phi)
    bridge.write_vector_attribute(mesh, bridge.BEND_AXES_ATTR, "EDGE", phi3)
    return fp3, psi, phi3


# --- bind inputs -------------------------------------------------------------------------------


def anisotropic_bend(obj, a: bridge.MeshArrays, dual) -> np.ndarray:
    """(E,3) bending stiffness per dual edge from the stored per-axis edge attribute."""
    phi3 = bridge.read_vector_attribute(obj.data, bridge.BEND_AXES_ATTR, "EDGE", len(a.edge_verts))
    if phi3 is None:
        raise BindError(
            "Anisotropic is on but there is no per-axis stiffness yet: run 'Stiffness from "
            "Paint' or 'Learn from Shape Keys'"
        )
    if not np.all(np.isfinite(phi3)) or (phi3 <= 0).any():
        raise BindError("Per-axis bending attribute has values <= 0: run 'Stiffness from Paint'")
    lp = _loop_poly(a)
    return amap.dual_edge_bend_axes(
        a.tris, dual, a.tri_poly, a.edge_verts, phi3, a.loop_edge, lp, a.n_polys
    )


def axes(obj, depsgraph=None) -> np.ndarray | None:
    """Anisotropy axes (3,3) in mesh coordinates from the axes Empty, None = local axes."""
    emp = _settings(obj).axes_empty
    if emp is None:
        return None
    m_obj = bridge.world_matrix(obj, depsgraph)
    m_emp = bridge.world_matrix(emp, depsgraph)
    if m_obj is None or m_emp is None:
        raise BindError(f"Axes Empty '{emp.name}' is not evaluated here")
    try:
        return amap.axes_from_matrices(m_obj, m_emp)
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise BindError(f"Axes Empty '{emp.name}': {exc}") from exc


def store_bind_axes(obj) -> None:
    """Freeze the axes Empty's current orientation for the next bind (validated first)."""
    s = _settings(obj)
    if s.anisotropic and s.axes_empty is not None:
        s.bind_axes = axes(obj).ravel().tolist()


def bound_axes(obj) -> np.ndarray | None:
    """Axes the solver is built with: those frozen at bind, None = the object's local axes."""
    s = _settings(obj)
    if not s.anisotropic or s.axes_empty is None:
        return None
    try:  # stored as float32: back to an exact rotation for the solver
        return amap.nearest_rotation(np.array(tuple(s.bind_axes)).reshape(3, 3))
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise BindError("Stored anisotropy axes are invalid - click Bind again") from exc


def region_faces(obj, a: bridge.MeshArrays) -> np.ndarray | None:
    """Triangles of the region of interest: those of the polygons whose vertices are all in the
    region group (None when no region is set)."""
    name = _settings(obj).region_group
    if not name:
        return None
    w = bridge.vertex_group_weights(obj, [name]).get(name)
    if w is None:
        raise BindError(f"Region: vertex group '{name}' not found")
    polys = am.anchor_polygons(w >= 0, a.loop_vert, _loop_poly(a), a.n_polys)
    faces = np.flatnonzero(polys[a.tri_poly]).astype(np.int64)
    if len(faces) == 0:
        raise BindError(f"Region: vertex group '{name}' contains no whole face")
    return faces


def check_anchors_in_region(region, anchor_faces, names) -> None:
    inside = np.zeros(int(max(region.max(), max(f.max() for f in anchor_faces))) + 1, bool)
    inside[region] = True
    for faces, name in zip(anchor_faces, names, strict=True):
        out = ~inside[faces]
        if out.any():
            raise BindError(
                f"Anchor '{name}' has {int(out.sum())} triangle(s) outside the region: "
                "add them to the region group or shrink the anchor"
            )


# --- learning from shape keys -----------------------------------------------------------------


def learn_from_shape_keys(obj, progress: Callable[[float, str], None] | None = None) -> dict:
    """Learn bending and shear stiffness from the object's shape keys (example poses of the
    Basis, paper Sec. 6), write the stiffness attributes the bind uses and the paint layer in
    use (vertex groups, or the colour attribute, via the inverse log map) so the user can
    refine them by painting.

    Validates everything before writing anything."""
    progress = progress or (lambda _f, _t: None)
    s = _settings(obj)
    mesh = obj.data
    if len(mesh.polygons) == 0:
        raise BindError("Mesh has no faces")
    names = amap.learn_key_names(bridge.shape_key_info(obj), s.learn_filter)
    if not names:
        extra = f" matching '{s.learn_filter}'" if s.learn_filter.strip() else ""
        raise BindError(
            f"No example poses: add unmuted shape keys{extra} besides the Basis "
            "(the add-on's own 'Material Deform' and 'MD Bake' keys are ignored)"
        )
    if s.stiffness_source == "COLOR_ATTRIBUTE" and not bridge.color_attribute_writable(
        obj, s.color_attribute
    ):
        raise BindError(
            f"Cannot write color attribute '{s.color_attribute}': the name is taken by a vertex "
            "group or another attribute (pick another Color Attribute name)"
        )
    progress(0.05, "Material Deform: reading shape keys")
    a = bridge.mesh_arrays(mesh)
    poses = [bridge.shape_key_positions(obj, n) for n in names]
    for n, p in zip(names, poses, strict=True):
        if not np.all(np.isfinite(p)):
            raise BindError(f"Shape key '{n}' has non-finite coordinates")
    rot = axes(obj) if s.anisotropic else None
    rest = a.rest
    if rot is not None:  # learn the per-axis components along the chosen axes
        rest = rest @ rot
        poses = [p @ rot for p in poses]
    md = _core()
    progress(0.2, f"Material Deform: learning from {len(poses)} pose(s)")
    span = s.stiffness_span
    try:
        # Region-level bending uses the settings that won on the cat benchmark (docs/quality.md).
        region = 0 if s.anisotropic else int(s.learn_region)
        preset = {"region": region, "smoothing": 30, "clamp_percent": 5.0} if region else {}
        bend, shear = md.learn_stiffness(
            rest, a.tris, poses, anisotropic=bool(s.anisotropic), eps=10.0**-span, **preset
        )
    except (ValueError, RuntimeError) as exc:
        raise BindError(f"Learning failed: {exc}") from exc
    progress(0.7, "Material Deform: writing stiffness and paint layers")
    dual = np.asarray(md.dual_edges(a.tris), dtype=np.int64).reshape(-1, 2)
    de = sm.dual_to_mesh_edge(a.tris, dual, a.edge_verts)
    n_e = len(a.edge_verts)
    n_v = len(rest)
    lp = _loop_poly(a)
    psi = amap.triangle_to_polygon_stiffness(shear, a.tri_poly, a.n_polys)
    phi_edge, has = amap.dual_values_to_edges(bend, de, n_e)
    edge_paint = sm.stiffness_to_paint(phi_edge, span)
    vpaint = amap.edge_paint_to_vertices(edge_paint, a.edge_verts, has, n_v)  # (n,) or (n,3)
    written = {}
    if s.anisotropic:
        phi = np.exp(np.log(phi_edge).mean(axis=1))  # scalar fallback: geometric mean of axes
        bridge.write_vector_attribute(mesh, bridge.BEND_AXES_ATTR, "EDGE", phi_edge)
    else:
        phi = phi_edge
    if s.stiffness_source == "COLOR_ATTRIBUTE":
        # R, G, B = x, y, z (grey when isotropic); the shear then follows their mean
        rgb = vpaint if vpaint.ndim == 2 else np.repeat(vpaint[:, None], 3, axis=1)
        bridge.write_color_attribute_vertex_rgb(mesh, s.color_attribute, rgb)
        written[s.color_attribute] = s.color_attribute
    elif s.anisotropic:
        for c, g in enumerate(amap.axis_group_names(s.stiffness_group)):
            written[g] = bridge.set_vertex_group_weights(obj, g, vpaint[:, c])
        # the plain group carries the shear in anisotropic mode
        shear_vp = amap.face_paint_to_vertices(
            sm.stiffness_to_paint(psi, span), a.loop_vert, lp, n_v
        )
        g = s.stiffness_group
        written[g] = bridge.set_vertex_group_weights(obj, g, shear_vp)
    else:
        g = s.stiffness_group
        written[g] = bridge.set_vertex_group_weights(obj, g, vpaint)
    bridge.write_float_attribute(mesh, bridge.SHEAR_ATTR, "FACE", psi)
    bridge.write_float_attribute(mesh, bridge.BEND_ATTR, "EDGE", phi)
    progress(1.0, "")
    return {"keys": names, "bend": bend, "shear": shear, "psi": psi, "phi": phi, "groups": written}


def _core():
    try:
        return core.load()
    except ImportError as exc:
        raise BindError(str(exc)) from exc
