"""Learn from Shape Keys (paper Sec. 6): example poses of the Basis -> bending and shear
stiffness, written as the stiffness attributes a bind reads and as the paint layer in use (so the
user refines the result by painting)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from . import aniso_map as amap
from . import bridge
from . import stiffness_map as sm
from .methods import material
from .model import BindError, load_core, settings


def learn_from_shape_keys(obj, progress: Callable[[float, str], None] | None = None) -> dict:
    """Learn bending and shear stiffness from the object's shape keys (example poses of the
    Basis, paper Sec. 6), write the stiffness attributes the bind uses and the paint layer in
    use (vertex groups, or the colour attribute, via the inverse log map) so the user can
    refine them by painting.

    Validates everything before writing anything."""
    progress = progress or (lambda _f, _t: None)
    s = settings(obj)
    mesh = obj.data
    if len(mesh.polygons) == 0:
        raise BindError("Mesh has no faces")
    names = amap.learn_key_names(bridge.shape_key_info(obj), s.learn_filter, s.output_key_name)
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
    rot = material.axes(obj) if s.anisotropic else None
    rest = a.rest
    if rot is not None:  # learn the per-axis components along the chosen axes
        rest = rest @ rot
        poses = [p @ rot for p in poses]
    md = load_core()
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
    lp = sm.loop_polygon_index(a.loop_start, a.loop_total)
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
