"""Material-aware method in Blender: the region of interest (paper Sec. 7)."""

import bpy
import numpy as np
from helpers import (
    add_anchor,
    anchor_vertices,
    draw_panel,
    expect_error,
    output,
    paint,
    rest,
    snapshot,
    triangles,
    tube,
    two_end_anchors,
    update,
)


def test_region_outside_bit_identical_boundary_at_rest():
    obj = tube(rings=21)
    paint(obj, "Region", lambda v: 1.0)
    vg = obj.vertex_groups["Region"]
    vg.remove([v.index for v in obj.data.vertices if v.co.z < -1.0 - 1e-4])
    obj.material_deform.region_group = "Region"
    # one anchor is enough: the region's border holds the bar
    top = add_anchor(obj, lambda p: p.center.z > 1.999)
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
    r = rest(obj)
    top.empty.location.x += 1.0
    top.empty.rotation_euler.y = 0.4
    update()
    x = output(obj)
    outside = r[:, 2] < -1.0 - 1e-4
    border = np.isclose(r[:, 2], -1.0)
    assert outside.sum() == 8 * 5 and border.sum() == 8
    assert x[outside].tobytes() == r[outside].tobytes()  # bit-identical
    assert x[border].tobytes() == r[border].tobytes()  # border at rest
    inside = r[:, 2] > -1.0 + 1e-4
    moved = np.linalg.norm(x - r, axis=1)
    assert moved[np.isclose(r[:, 2], 2.0)].min() > 0.9  # the anchor followed its Empty
    assert 0.05 < moved[np.isclose(r[:, 2], 0.0)].mean() < 0.9
    # the inside is the numpy library's solve on the same inputs (default stiffness)
    import matdeform as md

    tris, _ = triangles(obj)
    in_region = ~outside
    region = np.flatnonzero(in_region[tris].all(axis=1))
    cap = np.zeros(len(r), bool)
    cap[anchor_vertices(obj, top)] = True
    anchor = np.flatnonzero(cap[tris].all(axis=1))
    t = np.array(obj.matrix_world.inverted() @ top.empty.matrix_world) @ np.linalg.inv(
        np.array(top.bind_matrix).reshape(4, 4)
    )
    d = md.MaterialDeformer(r.astype(float), tris, [anchor], region=region)
    want = d.deform(t[None])
    diag = np.linalg.norm(r.max(axis=0) - r.min(axis=0))
    np.testing.assert_allclose(x[inside], want[inside], atol=1e-5 * diag)
    log = draw_panel()
    assert "region_group" in log and "anisotropic" in log
    assert "mesh.material_deform_learn_stiffness" in log and "learn_filter" in log
    obj.material_deform.anisotropic = True
    assert "axes_empty" in draw_panel()


def test_region_changes_mark_bind_stale():
    obj = tube()
    paint(obj, "Region", lambda v: 1.0)
    obj.material_deform.region_group = "Region"
    two_end_anchors(obj)
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
    obj.vertex_groups["Region"].remove([v.index for v in obj.data.vertices if v.co.z == 0.0])
    # repainting the region group: detected by the fingerprint
    expect_error(bpy.ops.object.material_deform_update, "region")
    assert bpy.ops.object.material_deform_reset() == {"FINISHED"}
    obj.material_deform.region_group = ""
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
    obj.material_deform.region_group = "Region"  # changing the setting
    expect_error(bpy.ops.object.material_deform_update, "region or anisotropy")


def test_anchor_outside_region_is_refused():
    obj = tube()
    two_end_anchors(obj)
    paint(obj, "Region", lambda v: 1.0)
    obj.vertex_groups["Region"].remove([v.index for v in obj.data.vertices if v.co.z < -1.5])
    obj.material_deform.region_group = "Region"
    before = snapshot(obj)
    expect_error(bpy.ops.object.material_deform_bind, "outside the region")
    assert snapshot(obj) == before and not obj.material_deform.bound
    obj.material_deform.region_group = "Nope"
    expect_error(bpy.ops.object.material_deform_bind, "Region: vertex group 'Nope' not found")
    assert snapshot(obj) == before
