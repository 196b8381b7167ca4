"""Learning stiffness from shape keys in Blender (paper Sec. 6)."""

import math

import bpy
import numpy as np
import pytest
from helpers import (
    add_anchor,
    attr,
    expect_error,
    face_rotation_angles,
    group_weights,
    output,
    rest,
    snapshot,
    triangles,
    tube,
    two_end_anchors,
    update,
)


def bend_key(obj, name, angle, axis, z0=0.0, length=0.4):
    """Shape key bending the bar (along z, radius 0.5) at one joint: a circular arc about the
    ``axis`` ("X" or "Y") over z0 <= z <= z0 + length (two ring spacings), rigid below and
    above; the joint's inner side keeps a positive length (radius length/angle > 0.5)."""
    kb = obj.shape_key_add(name=name, from_mix=False)
    big_r = length / angle
    for i, v in enumerate(obj.data.vertices):
        x, y, z = v.co
        u, w = (y, x) if axis == "X" else (-x, y)  # u: across the bend, w: along the hinge
        dz = z - z0
        if dz > 0:
            s = min(dz, length)
            phi = s / big_r
            u, dz = -big_r + (big_r + u) * math.cos(phi), (big_r + u) * math.sin(phi)
            if z - z0 > length:  # rigid continuation along the end tangent
                u -= (z - z0 - length) * math.sin(phi)
                dz += (z - z0 - length) * math.cos(phi)
        x, y = (w, u) if axis == "X" else (-u, w)
        kb.data[i].co = (x, y, z0 + dz)
    return kb


def edge_mid_z(obj):
    me = obj.data
    return np.array([np.mean([me.vertices[i].co.z for i in e.vertices]) for e in me.edges])


def test_learn_from_shape_keys_finds_the_joint():
    """Two poses bending the bar about x and about y at the same joint (0 <= z <= 0.4)."""
    obj = tube(rings=21)
    obj.shape_key_add(name="Basis")
    bend_key(obj, "Bend X", 0.6, "X")
    bend_key(obj, "Bend Y", -0.6, "Y")
    junk = obj.shape_key_add(name="Material Deform", from_mix=False)  # the add-on's own key:
    junk.data[0].co.x += 50.0  # ignored, else this vertex would dominate
    assert bpy.ops.mesh.material_deform_learn_stiffness() == {"FINISHED"}
    phi = attr(obj, "md_bend_stiffness")
    psi = attr(obj, "md_shear_stiffness")
    z = edge_mid_z(obj)
    joint = np.isclose(z, 0.2, atol=0.01)  # the ring in the middle of the joint
    zone = (z > -0.01) & (z < 0.41)
    far = np.abs(z - 0.2) > 0.35
    # the lowest bending stiffness is at the joint, the rest stays stiff
    assert 0.0 <= z[np.argmin(phi)] <= 0.4
    assert phi[joint].min() == pytest.approx(1e-3, rel=0.01)  # eps = 10**-span
    assert phi[joint].max() < 0.25 and phi[zone].max() < 0.9
    assert phi[far].min() > 0.99
    assert psi.min() == pytest.approx(1e-3, rel=0.01) and np.median(psi) > 0.99
    # paint layer written back: inverse log map, averaged to the vertices
    w = group_weights(obj, "Stiffness")
    vz = np.array([v.co.z for v in obj.data.vertices])
    assert w[np.isclose(vz, 0.2)].max() < 0.7  # joint ring: flexible
    assert w[(vz < -0.1) | (vz > 0.5)].min() > 0.99  # away from it: stiff
    paint_e = np.clip(1 + np.log10(phi.astype(float)) / 3.0, 0, 1)  # inverse of the log map
    for v in np.flatnonzero(np.isclose(vz, 0.2)):
        incident = [e.index for e in obj.data.edges if v in e.vertices]
        assert w[v] == pytest.approx(paint_e[incident].mean(), abs=1e-5)
    # refining by painting goes through the normal path and keeps the joint flexible
    assert bpy.ops.mesh.material_deform_stiffness_from_paint() == {"FINISHED"}
    phi2 = attr(obj, "md_bend_stiffness")
    assert phi2[joint].max() < 0.3 and phi2[np.abs(z - 0.2) > 0.55].min() > 0.99


def test_learn_region_level_finds_the_joint():
    """Region-level learning (learn_region > 0): bending is still softest at the joint, and the
    joint is softer than the bar's far ends."""
    obj = tube(rings=21)
    obj.shape_key_add(name="Basis")
    bend_key(obj, "Bend X", 0.6, "X")
    bend_key(obj, "Bend Y", -0.6, "Y")
    obj.material_deform.learn_region = 20
    assert bpy.ops.mesh.material_deform_learn_stiffness() == {"FINISHED"}
    phi = attr(obj, "md_bend_stiffness")
    z = edge_mid_z(obj)
    assert 0.0 <= z[np.argmin(phi)] <= 0.4
    joint = np.isclose(z, 0.2, atol=0.01)
    far = np.abs(z - 0.2) > 0.8
    print("region-level joint max", phi[joint].max(), "far min", phi[far].min())
    assert phi[joint].max() < 0.1 < 0.9 < phi[far].min(), (phi[joint].max(), phi[far].min())


def joint_bend(learn):
    """Bind the two-pose bar (learned or uniform material, paper-mode anchors at both ends),
    bend the top 90 degrees about x and return how much of it the joint takes: mean rotation
    angle (degrees) of the triangles just above the joint (0.4 < z < 0.6) minus just below it
    (-0.2 < z < 0)."""
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    obj = tube(rings=21)
    obj.shape_key_add(name="Basis")
    bend_key(obj, "Bend X", 0.6, "X")
    bend_key(obj, "Bend Y", -0.6, "Y")
    if learn:
        assert bpy.ops.mesh.material_deform_learn_stiffness() == {"FINISHED"}
    top = add_anchor(obj, lambda p: p.center.z > 1.999, mode="ROTATION")
    add_anchor(obj, lambda p: p.center.z < -1.999, mode="ROTATION")
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
    top.empty.rotation_euler.x = math.pi / 2
    update()
    tris, _ = triangles(obj)
    ang = np.degrees(face_rotation_angles(rest(obj), output(obj), tris))
    z = rest(obj)[tris].mean(axis=1)[:, 2]
    return float(ang[(z > 0.4) & (z < 0.6)].mean() - ang[(z > -0.2) & (z < 0)].mean())


def test_learned_material_bends_at_the_joint():
    """New pose with the learned stiffness: the joint takes most of a 90 degree bend (70 deg
    seen on Blender 3.4 / bpy 4.5), a uniform bar spreads it (13 deg over the same span)."""
    uniform, learned = joint_bend(False), joint_bend(True)
    assert uniform == pytest.approx(90 * 0.6 / 4.0, abs=3.0)
    assert learned > 60.0 and learned > 4 * uniform, (learned, uniform)


def test_learn_anisotropic_per_axis_and_filter():
    obj = tube(rings=21)
    obj.shape_key_add(name="Basis")
    bend_key(obj, "pose bend", 0.6, "X", z0=0.6)  # joint 0.6 <= z <= 1.0, about x
    other = bend_key(obj, "other", 0.6, "Y", z0=-0.6)  # joint -0.6 <= z <= -0.2, about y
    s = obj.material_deform
    s.anisotropic = True
    s.learn_filter = "POSE"  # case-insensitive substring: only 'pose bend'
    assert bpy.ops.mesh.material_deform_learn_stiffness() == {"FINISHED"}
    phi3 = attr(obj, "md_bend_stiffness_xyz", 3)
    z = edge_mid_z(obj)
    joint, other_joint = np.isclose(z, 0.8, atol=0.01), np.isclose(z, -0.4, atol=0.01)

    def zone(z, z0):
        return (z > z0 - 0.01) & (z < z0 + 0.41)

    assert phi3[joint, 0].min() == pytest.approx(1e-3, rel=0.01)  # bent about x there
    assert phi3[joint, 0].max() < 0.01
    # never bent about z; about y only a little, at the joint (the diagonal faces at the
    # square bar's corners shear, and their polar rotation has a y part): each axis differs
    assert phi3[:, 2].min() > 0.99
    assert phi3[joint, 1].min() > 0.4 and phi3[~zone(z, 0.6), 1].min() > 0.99
    assert phi3[other_joint].min() > 0.99  # the filtered-out key's joint stays stiff
    for g in ("Stiffness X", "Stiffness Y", "Stiffness Z", "Stiffness"):
        assert g in obj.vertex_groups
    wx, wy = group_weights(obj, "Stiffness X"), group_weights(obj, "Stiffness Y")
    vz = np.array([v.co.z for v in obj.data.vertices])
    ring = np.isclose(vz, 0.8)
    assert wx[ring].max() < 0.7 and wy[ring].min() > 0.9 and wy.min() > 0.9
    # muting a key deselects it; with the filter cleared only 'other' (about y) is used
    s.learn_filter = ""
    obj.data.shape_keys.key_blocks["pose bend"].mute = True
    assert other.mute is False
    assert bpy.ops.mesh.material_deform_learn_stiffness() == {"FINISHED"}
    phi3 = attr(obj, "md_bend_stiffness_xyz", 3)
    assert phi3[other_joint, 1].min() == pytest.approx(1e-3, rel=0.01)
    assert phi3[other_joint, 0].min() > 0.4 and phi3[~zone(z, -0.6), 0].min() > 0.99
    assert phi3[joint].min() > 0.99 and phi3[:, 2].min() > 0.99
    # the learned per-axis field binds
    two_end_anchors(obj)
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}


def test_learn_writes_the_color_attribute_when_that_is_the_paint_source():
    obj = tube(rings=21)
    obj.shape_key_add(name="Basis")
    bend_key(obj, "Bend X", 0.6, "X")
    s = obj.material_deform
    s.stiffness_source = "COLOR_ATTRIBUTE"
    vz = np.array([v.co.z for v in obj.data.vertices])
    ring = np.isclose(vz, 0.2)
    for aniso in (False, True):
        s.anisotropic = aniso
        assert bpy.ops.mesh.material_deform_learn_stiffness() == {"FINISHED"}
        assert len(obj.vertex_groups) == 0  # only the paint layer in use is written
        ca = obj.data.color_attributes["Stiffness"]
        rgba = np.empty(len(ca.data) * 4, np.float32)
        ca.data.foreach_get("color_srgb" if hasattr(ca.data[0], "color_srgb") else "color", rgba)
        rgba = rgba.reshape(-1, 4)
        if aniso:  # bent about x only: R (x) flexible at the joint, G and B stiff
            assert rgba[ring, 0].max() < 0.7 and rgba[:, 1:3].min() > 0.9
        else:  # grey
            assert rgba[ring, 0].max() < 0.75 and rgba[np.abs(vz - 0.2) > 0.15, 0].min() > 0.9
            np.testing.assert_allclose(rgba[:, 1], rgba[:, 0], atol=1e-6)
        # Stiffness from Paint reads it back: the joint stays the most flexible place
        phi_learned = attr(obj, "md_bend_stiffness").copy()
        assert bpy.ops.mesh.material_deform_stiffness_from_paint() == {"FINISHED"}
        z = edge_mid_z(obj)
        phi = (
            attr(obj, "md_bend_stiffness_xyz", 3)[:, 0] if aniso else attr(obj, "md_bend_stiffness")
        )
        assert abs(z[np.argmin(phi)] - 0.2) < 0.21 and abs(z[np.argmin(phi_learned)] - 0.2) < 0.21
    # a vertex group holding the colour attribute's name blocks it (Blender 4+): refused, untouched
    obj.data.color_attributes.remove(obj.data.color_attributes["Stiffness"])
    obj.vertex_groups.new(name="Stiffness")
    before = snapshot(obj)
    expect_error(bpy.ops.mesh.material_deform_learn_stiffness, "Cannot write color attribute")
    assert snapshot(obj) == before


def test_learn_without_poses_is_refused():
    obj = tube()
    before = snapshot(obj)
    expect_error(bpy.ops.mesh.material_deform_learn_stiffness, "No example poses")
    assert snapshot(obj) == before and len(obj.vertex_groups) == 0
    two_end_anchors(obj)
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}  # Basis + own output key only
    groups = len(obj.vertex_groups)
    before = snapshot(obj)
    expect_error(bpy.ops.mesh.material_deform_learn_stiffness, "No example poses")
    assert snapshot(obj) == before and len(obj.vertex_groups) == groups
    obj.shape_key_add(name="Pose", from_mix=False)
    obj.material_deform.learn_filter = "walk"
    expect_error(bpy.ops.mesh.material_deform_learn_stiffness, "matching 'walk'")


def test_learn_anisotropic_along_the_axes_empty():
    """With an axes Empty turned 90 degrees about Y (its z axis is the object's x axis), a
    pose bending about the object's x axis is learned in the z component."""
    obj = tube(rings=21)
    obj.shape_key_add(name="Basis")
    bend_key(obj, "Bend", 0.6, "X")
    emp = bpy.data.objects.new("Axes", None)
    bpy.context.scene.collection.objects.link(emp)
    emp.rotation_euler = (0.0, math.pi / 2, 0.0)
    update()
    s = obj.material_deform
    s.anisotropic, s.axes_empty = True, emp
    assert bpy.ops.mesh.material_deform_learn_stiffness() == {"FINISHED"}
    phi3 = attr(obj, "md_bend_stiffness_xyz", 3)
    joint = np.isclose(edge_mid_z(obj), 0.2, atol=0.01)
    assert phi3[joint, 2].max() < 0.01  # about the Empty's z = the object's x
    assert phi3[:, 0].min() > 0.99  # the Empty's x is the bar axis: no twist
    assert phi3[joint, 1].min() > 0.4
