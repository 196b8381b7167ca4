"""Stiffness from paint, isotropic and per axis, the stored stiffness a bind reads, and Show.

Paint (a vertex group or a colour attribute) -> per-face shear psi and per-edge bending phi,
stored as mesh attributes (``bridge.SHEAR_ATTR``, ``BEND_ATTR``, ``BEND_AXES_ATTR``) that every
method reads at bind. The numpy maths is in ``stiffness_map`` / ``aniso_map``.
"""

from __future__ import annotations

import numpy as np

from . import aniso_map as amap
from . import bridge
from . import stiffness_map as sm
from .model import BindError, settings


def _loop_poly(a: bridge.MeshArrays) -> np.ndarray:
    return sm.loop_polygon_index(a.loop_start, a.loop_total)


def stiffness_from_paint(obj) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Convert the painted group / colour attribute to per-face psi and per-edge phi and store
    them as mesh attributes. Returns (face paint, psi, phi); anisotropic: phi is (e,3)."""
    s = settings(obj)
    mesh = obj.data
    if len(mesh.polygons) == 0:
        raise BindError("Mesh has no faces")
    if s.anisotropic:
        return anisotropic_from_paint(obj)
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
    loop_poly = _loop_poly(a)
    face_paint = sm.face_paint_from_vertex(vertex_paint, a.loop_vert, loop_poly, a.n_polys)
    psi = sm.paint_to_stiffness(face_paint, s.stiffness_span)
    phi = sm.edge_stiffness(psi, a.loop_edge, loop_poly, len(a.edge_verts))
    bridge.write_float_attribute(mesh, bridge.SHEAR_ATTR, "FACE", psi)
    bridge.write_float_attribute(mesh, bridge.BEND_ATTR, "EDGE", phi)
    return face_paint, psi, phi


def axis_vertex_paint(obj) -> np.ndarray:
    """(n,3) paint per vertex and axis: the groups '<group> X/Y/Z' or the colour's R, G, B."""
    s = settings(obj)
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
    s = settings(obj)
    mesh = obj.data
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


def _check_values(values, what: str) -> None:
    if not np.all(np.isfinite(values)):
        bad = int((~np.isfinite(values)).sum())
        raise BindError(
            f"{what} attribute has {bad} NaN or infinite value(s): run 'Stiffness from Paint'"
        )
    if (values <= 0).any():
        raise BindError(
            f"{what} attribute has values <= 0 (min {values.min():.3g}): run 'Stiffness from Paint'"
        )


def stored_stiffness(obj, a: bridge.MeshArrays) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(psi (P,) per polygon, phi (e,) per mesh edge) as stored by Stiffness from Paint or
    Learn, validated; None for a field that was never computed (uniform shear; bending derived
    from shear). An attribute of our name with the wrong type or domain is an error, not
    silently ignored."""
    mesh = obj.data
    for name, domain, dtype in (
        (bridge.SHEAR_ATTR, "FACE", "FLOAT"),
        (bridge.BEND_ATTR, "EDGE", "FLOAT"),
    ):
        found = bridge.attribute_kind(mesh, name)
        if found is not None and found != (domain, dtype):
            raise BindError(
                f"Attribute '{name}' is {found[1]} on {found[0]}, expected FLOAT on {domain}: "
                "remove or rename it, then run 'Stiffness from Paint'"
            )
    psi = bridge.read_float_attribute(mesh, bridge.SHEAR_ATTR, "FACE", a.n_polys)
    if psi is None:
        return None, None
    _check_values(psi, "Stiffness")
    phi = bridge.read_float_attribute(mesh, bridge.BEND_ATTR, "EDGE", len(a.edge_verts))
    if phi is not None:
        _check_values(phi, "Bending")
    return psi, phi


def _field_values(obj, a: bridge.MeshArrays, field: str) -> tuple[np.ndarray, str]:
    """Stiffness of the shown field and where it lives: ((P,) per polygon, "FACE") or
    ((e,) per edge, "EDGE")."""
    mesh = obj.data
    if field == "SHEAR":
        psi = bridge.read_float_attribute(mesh, bridge.SHEAR_ATTR, "FACE", a.n_polys)
        if psi is None:
            raise BindError("No stiffness stored yet: run 'Stiffness from Paint' first")
        return psi, "FACE"
    n_e = len(a.edge_verts)
    if field == "BEND":
        phi = bridge.read_float_attribute(mesh, bridge.BEND_ATTR, "EDGE", n_e)
        if phi is None:
            raise BindError("No bending stiffness stored yet: run 'Stiffness from Paint' first")
        return phi, "EDGE"
    axis = "XYZ".index(field[-1])
    phi3 = bridge.read_vector_attribute(mesh, bridge.BEND_AXES_ATTR, "EDGE", n_e)
    if phi3 is None:
        raise BindError(
            "No per-axis bending stored yet: with Anisotropic on, run 'Stiffness from Paint' "
            "or 'Learn from Shape Keys'"
        )
    return phi3[:, axis], "EDGE"


def show_stiffness(obj, field: str = "SHEAR") -> np.ndarray:
    """Write the display colour attribute (blue = flexible, red = stiff) from a stored field:
    "SHEAR" (per face), "BEND" or "BEND_X/Y/Z" (per edge, averaged at each vertex over the
    edges between two faces, as Learn writes its paint). Makes it the active colour attribute
    (Solid > Attribute shading shows the active one) and remembers the one it replaced.
    Returns the paint value of every corner."""
    s = settings(obj)
    mesh = obj.data
    a = bridge.mesh_arrays(mesh)
    values, domain = _field_values(obj, a, field)
    lp = _loop_poly(a)
    paint = sm.stiffness_to_paint(values, s.stiffness_span)
    if domain == "FACE":
        corner = paint[lp]
    else:
        inner = np.bincount(a.loop_edge, minlength=len(a.edge_verts)) >= 2
        vertex = amap.edge_paint_to_vertices(paint, a.edge_verts, inner, len(a.rest), fill=1.0)
        corner = vertex[a.loop_vert]
    prev = bridge.active_color_name(mesh)
    if prev != bridge.DISPLAY_ATTR:
        s.display_prev_color = prev
    bridge.write_corner_colors(mesh, bridge.DISPLAY_ATTR, sm.stiffness_colors(corner))
    return corner


def hide_stiffness(obj) -> bool:
    """Remove the display colour attribute and make the colour attribute Show replaced active
    again. False if nothing was shown."""
    s = settings(obj)
    removed = bridge.remove_attribute(obj.data, bridge.DISPLAY_ATTR)
    if s.display_prev_color:
        bridge.set_active_color(obj.data, s.display_prev_color)
    s.display_prev_color = ""
    return removed


def keep_display_out_of_paint(obj) -> bool:
    """Vertex Paint paints the active colour attribute: when the display one is active there,
    make the paint layer active instead (the one Show replaced, the stiffness colour attribute,
    any other, or a new stiffness attribute). True if it switched."""
    mesh = obj.data
    if obj.mode != "VERTEX_PAINT" or bridge.active_color_name(mesh) != bridge.DISPLAY_ATTR:
        return False
    s = settings(obj)
    others = [c.name for c in mesh.color_attributes if c.name != bridge.DISPLAY_ATTR]
    for name in (s.display_prev_color, s.color_attribute, *others):
        if name and name != bridge.DISPLAY_ATTR and bridge.set_active_color(mesh, name):
            return True
    bridge.create_color_attribute(mesh, s.color_attribute or "Stiffness")
    return True


def weight_paint_into_stiffness(obj) -> bool:
    """On entering Weight Paint with an anchor's vertex group active (Add Anchor makes its group
    the active one when the mesh had none): make the stiffness group the one painted, creating
    it if missing, so that strokes meant for the stiffness do not grow the anchor. Only with
    the vertex-group paint source. True if it switched."""
    s = settings(obj)
    active = obj.vertex_groups.active
    anchor_groups = {a.vertex_group for a in s.anchors}
    if s.stiffness_source != "VERTEX_GROUP" or active is None or active.name not in anchor_groups:
        return False
    add_paint_layer(obj)
    return True


def add_paint_layer(obj) -> tuple[list[str], bool]:
    """Create the paint layer of the current Paint Source if it is missing (the vertex group,
    with its X / Y / Z groups when anisotropic; or the colour attribute, black = flexible) and
    make it the active one for painting. Returns (names, whether any was created)."""
    s = settings(obj)
    if s.stiffness_source == "VERTEX_GROUP":
        names = [s.stiffness_group]
        if s.anisotropic:
            names += list(amap.axis_group_names(s.stiffness_group))
        created = [bridge.ensure_vertex_group(obj, n) for n in names]
        bridge.set_active_vertex_group(obj, s.stiffness_group)
        return names, any(created)
    name = s.color_attribute
    if obj.data.color_attributes.get(name) is not None:
        bridge.set_active_color(obj.data, name)
        return [name], False
    if not bridge.color_attribute_writable(obj, name):
        raise BindError(
            f"Cannot create color attribute '{name}': the name is taken by a vertex group or "
            "another attribute (pick another Color Attribute name)"
        )
    bridge.create_color_attribute(obj.data, name)
    return [name], True
