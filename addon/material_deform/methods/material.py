"""Material-aware deformation (Popa, Julius, Sheffer 2006): ``matdeform.MaterialDeformer``.

Its own inputs: the anisotropy axes (paper Sec. 5; an Empty's orientation frozen at bind) with
the per-axis bending stiffness, and the region of interest (Sec. 7). Its settings are the
top-level ``anisotropic``, ``axes_empty`` and ``region_group`` properties (kept there so files
saved before there were several methods still load).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import anchor_math as am
from .. import aniso_map as amap
from .. import bridge
from .. import stiffness_map as sm
from ..model import BindError, load_core, settings
from .base import Method, Result, register_method


@dataclass
class Solver:
    deformer: object
    use_4x4: bool  # False: every anchor is Rotation + Scale, the (k,3,3) mode


def axes(obj, depsgraph=None) -> np.ndarray | None:
    """Anisotropy axes (3,3) in mesh coordinates from the axes Empty, None = local axes."""
    emp = settings(obj).axes_empty
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


def bound_axes(obj) -> np.ndarray | None:
    """Axes the solver is built with: those frozen at bind, None = the object's local axes."""
    s = settings(obj)
    if not s.anisotropic or s.axes_empty is None:
        return None
    try:  # stored as float32: back to an exact rotation for the solver
        return amap.nearest_rotation(np.array(tuple(s.bind_axes)).reshape(3, 3))
    except (ValueError, np.linalg.LinAlgError) as exc:
        raise BindError("Stored anisotropy axes are invalid - click Rebind") from exc


def stored_axis_bend(obj, a: bridge.MeshArrays) -> np.ndarray:
    """(e,3) per-axis bending stiffness per mesh edge, as stored, validated."""
    phi3 = bridge.read_vector_attribute(obj.data, bridge.BEND_AXES_ATTR, "EDGE", len(a.edge_verts))
    if phi3 is None:
        raise BindError(
            "Anisotropic is on but there is no per-axis stiffness yet: run 'Stiffness from "
            "Paint' or 'Learn from Shape Keys'"
        )
    if not np.all(np.isfinite(phi3)):
        raise BindError(
            "Per-axis bending attribute has NaN or infinite values: run 'Stiffness from Paint'"
        )
    if (phi3 <= 0).any():
        raise BindError("Per-axis bending attribute has values <= 0: run 'Stiffness from Paint'")
    return phi3


def dual_axis_bend(a: bridge.MeshArrays, dual, phi3) -> np.ndarray:
    """(E,3) bending stiffness per dual edge from the per-mesh-edge (e,3) one."""
    lp = sm.loop_polygon_index(a.loop_start, a.loop_total)
    return amap.dual_edge_bend_axes(
        a.tris, dual, a.tri_poly, a.edge_verts, phi3, a.loop_edge, lp, a.n_polys
    )


def region_faces(obj, a: bridge.MeshArrays) -> np.ndarray | None:
    """Triangles of the region of interest: those of the polygons whose vertices are all in the
    region group (None when no region is set)."""
    name = settings(obj).region_group
    if not name:
        return None
    w = bridge.vertex_group_weights(obj, [name]).get(name)
    if w is None:
        raise BindError(f"Region: vertex group '{name}' not found")
    lp = sm.loop_polygon_index(a.loop_start, a.loop_total)
    polys = am.anchor_polygons(w >= 0, a.loop_vert, lp, a.n_polys)
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


class MaterialMethod(Method):
    key = "MATERIAL"
    number = 0
    label = "Material-aware"
    description = (
        "Popa, Julius and Sheffer 2006: blend the anchors' transforms by the painted bending "
        "stiffness and place the shear in the soft parts (direct solve, every update exact)"
    )
    anchor_modes = frozenset({am.POSITION, am.ROTATION})

    def gather(self, obj, inputs, binding) -> None:
        s = settings(obj)
        a = inputs.arrays
        region = region_faces(obj, a)
        if region is not None:
            check_anchors_in_region(region, inputs.anchor_faces, inputs.names)
        inputs.region = region
        if s.anisotropic:
            inputs.extra["phi3"] = stored_axis_bend(obj, a)
            if binding and s.axes_empty is not None:
                # the axes Empty's orientation now, as it will read back from bind_axes
                now = axes(obj).astype(np.float32).astype(np.float64)
                inputs.extra["axes"] = amap.nearest_rotation(now)
            else:
                inputs.extra["axes"] = bound_axes(obj)

    def commit(self, obj, inputs) -> None:
        ax = inputs.extra.get("axes")
        if ax is not None:
            settings(obj).bind_axes = ax.ravel().tolist()

    def fingerprint(self, obj, inputs) -> list:
        ax = inputs.extra.get("axes")
        return [
            "whole mesh" if inputs.region is None else inputs.region,
            inputs.extra.get("phi3", "isotropic"),
            # integers: rounding floats could give -0.0 and 0.0 (different bytes)
            "local axes" if ax is None else np.rint(ax * 1e6).astype(np.int64),
        ]

    fingerprint_what = "method, region or anisotropy"

    def build(self, inputs) -> Solver:
        md = load_core()
        use_4x4, pinned = am.solve_plan(inputs.modes, inputs.anchor_faces, inputs.arrays.tris)
        if pinned is not None:
            pinned = inputs.compact_index(pinned)
        phi3 = inputs.extra.get("phi3")
        bend = inputs.bend if phi3 is None else dual_axis_bend(inputs.arrays, inputs.dual, phi3)
        try:
            d = md.MaterialDeformer(
                inputs.verts_c,
                inputs.tris_c,
                inputs.anchor_faces,
                shear=inputs.shear,
                bend=bend,
                pinned=pinned,
                region=inputs.region,
                axes=inputs.extra.get("axes"),
            )
        except (ValueError, RuntimeError) as exc:
            raise BindError(f"Solver rejected the mesh: {exc}") from exc
        return Solver(d, use_4x4)

    def solve(self, solver, transforms, state, budget, progress=None, rotations=None) -> Result:
        t = transforms if solver.use_4x4 else np.ascontiguousarray(transforms[:, :3, :3])
        # Rounded to float32 on the solver's threads, as the key stores it: the live update then
        # neither converts nor allocates a float64 result (~50 us at 50k faces).
        out = np.empty((solver.deformer.num_vertices, 3), np.float32)
        # the anchors' turns: Eq. 2 blends these logs (None: the principal ones)
        return Result(solver.deformer.deform(t, out=out, rotation_vectors=rotations))

    def check_live(self, obj, entry, depsgraph) -> None:
        """Rebind is needed if the anisotropy axes moved since bind. The axes come from an SVD
        (LAPACK, which keeps an OpenBLAS thread spinning in bpy 4.x), so they are recomputed
        only when the object's or the axes Empty's matrix changed since the last check."""
        s = settings(obj)
        if not s.anisotropic or s.axes_empty is None:
            return
        mats = [bridge.world_matrix(o, depsgraph) for o in (obj, s.axes_empty)]
        key = b"".join(m.tobytes() for m in mats if m is not None)
        if entry.state.get("axes_checked") == key:
            return
        now_axes = axes(obj, depsgraph)
        if now_axes is None or not np.allclose(now_axes, bound_axes(obj), atol=1e-6):
            raise BindError("Axes Empty changed since bind - click Rebind")
        entry.state["axes_checked"] = key

    def draw(self, layout, obj, entry) -> None:
        s = settings(obj)
        layout.prop(s, "anisotropic")
        if s.anisotropic:
            layout.prop(s, "axes_empty")
            if s.stiffness_source == "VERTEX_GROUP":
                layout.label(text="Paint one group per axis:")
                layout.label(text=f"{s.stiffness_group} X / Y / Z")
            else:
                layout.label(text="Paint R / G / B = x / y / z")
        layout.label(text="Deform Only (vertex group):")
        layout.prop_search(s, "region_group", obj, "vertex_groups", text="", icon="SELECT_SET")


register_method(MaterialMethod())
