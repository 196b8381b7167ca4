"""Demo scene, built by script: a tapered tentacle whose stiffness follows its girth (paper
Fig. 1/10) and a bar with a stiff middle (Fig. 4), each deformed twice by the same Empty moves:
uniform material (left) vs material-aware (right). Saves out/demo.blend and renders PNGs.
A second scene poses a tentacle and a bar by pyramid coordinates (method PYRAMID: the anchor
faces' vertices are the only control vertices, no painting): out/demo_pyramid.blend and
out/demo_pyramid_blender.png.

    blender -b --factory-startup --python scripts/demo_blender.py      (or scripts/demo_blender.sh)

The add-on is enabled from addon/ in this repository; the matdeform core must be importable
(demo_blender.sh puts the vendored build on MD_SYS_PATH).
"""

import math
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
for p in reversed(os.environ.get("MD_SYS_PATH", "").split(os.pathsep)):
    if p:
        sys.path.insert(0, p)
sys.path.insert(0, str(ROOT / "addon"))

import bpy  # noqa: E402
from mathutils import Matrix, Vector  # noqa: E402

OUT = ROOT / "out"


def enable_addon():
    import addon_utils

    addon_utils.enable("material_deform", default_set=True)
    assert hasattr(bpy.types, "MESH_OT_material_deform_bind"), "add-on failed to enable"


def tube(name, radius_at, length, rings, sides, location):
    """Tube along +Z from z=0 to z=length with n-gon caps; radius_at(t) for t in [0,1]."""
    verts, faces = [], []
    for r in range(rings):
        t = r / (rings - 1)
        rad = radius_at(t)
        for s in range(sides):
            a = 2 * math.pi * s / sides
            verts.append((rad * math.cos(a), rad * math.sin(a), length * t))
    faces.append(tuple(reversed(range(sides))))
    faces.append(tuple(range((rings - 1) * sides, rings * sides)))
    for r in range(rings - 1):
        for s in range(sides):
            a, b = r * sides + s, r * sides + (s + 1) % sides
            faces.append((a, b, b + sides, a + sides))
    me = bpy.data.meshes.new(name)
    me.from_pydata(verts, [], faces)
    for p in me.polygons:
        p.use_smooth = True
    obj = bpy.data.objects.new(name, me)
    obj.location = location
    bpy.context.scene.collection.objects.link(obj)
    return obj


def activate(obj):
    for o in bpy.context.view_layer.objects:
        o.select_set(False)
    bpy.context.view_layer.objects.active = obj
    obj.select_set(True)


def add_anchor(obj, pick):
    from material_deform.bridge import select_polygons_edit

    activate(obj)
    mask = [bool(pick(p)) for p in obj.data.polygons]
    bpy.ops.object.mode_set(mode="EDIT")
    select_polygons_edit(obj, mask)
    assert bpy.ops.mesh.material_deform_add_anchor() == {"FINISHED"}
    bpy.ops.object.mode_set(mode="OBJECT")
    return obj.material_deform.anchors[-1]


def paint(obj, weight_of):
    vg = obj.vertex_groups.new(name="Stiffness")
    for v in obj.data.vertices:
        vg.add([v.index], float(weight_of(v.co)), "REPLACE")
    activate(obj)
    assert bpy.ops.mesh.material_deform_stiffness_from_paint() == {"FINISHED"}
    assert bpy.ops.mesh.material_deform_show_stiffness() == {"FINISHED"}


def setup(obj, anchors, weight_of=None):
    """Paint (None = uniform material), anchor, bind; returns the anchors."""
    if weight_of is not None:
        paint(obj, weight_of)
    else:
        paint(obj, lambda co: 1.0)  # uniform: every face stiffness 1 (shows red)
    ancs = [add_anchor(obj, a) for a in anchors]
    activate(obj)
    assert bpy.ops.mesh.material_deform_bind() == {"FINISHED"}
    return ancs


def move(anchor, dloc, angle_y):
    """Translate the Empty by dloc and turn it about the world Y axis (the view axis), around
    its own origin."""
    e = anchor.empty
    c = e.matrix_world.translation.copy()
    turn = Matrix.Translation(c) @ Matrix.Rotation(angle_y, 4, "Y") @ Matrix.Translation(-c)
    e.matrix_world = Matrix.Translation(Vector(dloc)) @ turn @ e.matrix_world
    bpy.context.view_layer.update()


def label(text, location):
    cu = bpy.data.curves.new(text, "FONT")
    cu.body = text
    cu.align_x = "CENTER"
    cu.size = 0.45
    ob = bpy.data.objects.new(text, cu)
    ob.location = location
    ob.rotation_euler = (math.pi / 2, 0, 0)
    bpy.context.scene.collection.objects.link(ob)


def display_material():
    """Shows the md_stiffness_display colours in Cycles/EEVEE (Workbench reads them directly)."""
    mat = bpy.data.materials.new("Stiffness display")
    mat.use_nodes = True
    nt = mat.node_tree
    bsdf = nt.nodes.get("Principled BSDF")
    attr = nt.nodes.new("ShaderNodeAttribute")
    attr.attribute_name = "md_stiffness_display"
    nt.links.new(attr.outputs["Color"], bsdf.inputs["Base Color"])
    return mat


def build():
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    mat = display_material()

    # tentacle: radius 0.45 -> 0.06, stiffness ~ girth (paint = radius / max radius)
    r0, r1, length = 0.45, 0.06, 5.0

    def radius(t):
        return r0 + (r1 - r0) * t

    def girth(co):
        return max(0.0, min(1.0, math.hypot(co.x, co.y) / r0))

    tip_moves = ((2.2, 0.0, -1.2), 1.4)
    results = {}
    for i, (kind, w) in enumerate((("uniform", None), ("material", girth))):
        obj = tube(f"Tentacle {kind}", radius, length, 60, 16, (-6.5 + 3.0 * i, 0, 0))
        obj.data.materials.append(mat)
        base, tip = setup(
            obj, [lambda p: p.center.z < 1e-4, lambda p: p.center.z > length - 0.2], w
        )
        move(tip, *tip_moves)
        results[obj.name] = obj

    # bar: square-ish tube, stiff middle third (paint 1), flexible ends (paint 0)
    def stiff_middle(co):
        return 1.0 if abs(co.z - 2.5) < 0.85 else 0.0

    for i, (kind, w) in enumerate((("uniform", None), ("material", stiff_middle))):
        obj = tube(f"Bar {kind}", lambda t: 0.4, 5.0, 41, 4, (1.5 + 3.0 * i, 0, 0))
        obj.rotation_euler.z = math.pi / 4
        obj.data.materials.append(mat)
        for p in obj.data.polygons:
            p.use_smooth = False
        _bottom, top = setup(obj, [lambda p: p.center.z < 1e-4, lambda p: p.center.z > 4.999], w)
        move(top, (1.6, 0.0, -1.0), math.pi / 2)
        results[obj.name] = obj

    for x, text in (
        (-6.5, "uniform"),
        (-3.5, "girth-stiff"),
        (1.5, "uniform"),
        (4.5, "stiff middle"),
    ):
        label(text, (x, -1.0, 5.7))
    for ob in scene.objects:
        if ob.type == "EMPTY":
            ob.empty_display_size = 0.3
    return scene


def camera_and_light(scene):
    cam_data = bpy.data.cameras.new("Camera")
    cam_data.type = "ORTHO"
    cam_data.ortho_scale = 15.5
    cam = bpy.data.objects.new("Camera", cam_data)
    cam.location = (-0.5, -20, 3.2)
    cam.rotation_euler = (math.pi / 2, 0, 0)
    scene.collection.objects.link(cam)
    scene.camera = cam
    sun = bpy.data.objects.new("Sun", bpy.data.lights.new("Sun", "SUN"))
    sun.rotation_euler = (0.9, 0.2, -0.4)
    sun.data.energy = 3.0
    scene.collection.objects.link(sun)
    world = bpy.data.worlds.new("World")
    world.color = (0.8, 0.8, 0.8)
    scene.world = world
    scene.render.resolution_x, scene.render.resolution_y = 1600, 700
    scene.render.resolution_percentage = 100


def render(scene, path, color_type="VERTEX"):
    """Workbench (attribute colours) if it works headless here, else Cycles CPU."""
    scene.render.filepath = str(path)
    try:
        scene.render.engine = "BLENDER_WORKBENCH"
        scene.display.shading.light = "STUDIO"
        scene.display.shading.color_type = color_type
        bpy.ops.render.render(write_still=True)
        if path.exists():
            return "workbench"
    except RuntimeError as exc:
        print("Workbench failed:", exc)
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 16
    scene.world.use_nodes = False
    bpy.ops.render.render(write_still=True)
    return "cycles"


def build_pyramid():
    """Rest (grey, left of each pair) and posed by pyramid coordinates (blue): only the anchor
    faces' vertices are controlled (the tentacle's base cap and tip, the bar's two end caps),
    the rest keeps its local shape."""
    from material_deform import session

    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    grey, blue = bpy.data.materials.new("Rest"), bpy.data.materials.new("Pyramid")
    grey.diffuse_color, blue.diffuse_color = (0.6, 0.6, 0.6, 1), (0.25, 0.45, 0.85, 1)
    r0, r1, length = 0.45, 0.06, 5.0

    def radius(t):
        return r0 + (r1 - r0) * t

    posed = []
    for i, kind in enumerate(("rest", "posed")):
        obj = tube(f"Tentacle {kind}", radius, length, 60, 16, (-6.5 + 3.0 * i, 0, 0))
        obj.data.materials.append(grey if kind == "rest" else blue)
        if kind == "posed":
            obj.material_deform.method = "PYRAMID"
            ancs = [
                add_anchor(obj, lambda p: p.center.z < 1e-4),
                add_anchor(obj, lambda p: p.center.z > length - 0.2),
            ]
            posed.append((obj, ancs[1], ((2.2, 0.0, -1.2), 1.4)))
    for i, kind in enumerate(("rest", "posed")):
        obj = tube(f"Bar {kind}", lambda t: 0.4, 5.0, 41, 12, (1.5 + 3.0 * i, 0, 0))
        obj.data.materials.append(grey if kind == "rest" else blue)
        if kind == "posed":
            obj.material_deform.method = "PYRAMID"
            ancs = [
                add_anchor(obj, lambda p: p.center.z < 1e-4),
                add_anchor(obj, lambda p: p.center.z > 4.999),
            ]
            obj.material_deform.pyramid.stretch = True  # keeps the bar's girth (docs/pyramid.md)
            posed.append((obj, ancs[1], ((1.2, 0.0, -0.6), math.pi / 3)))
    for obj, tip, how in posed:
        activate(obj)
        assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
        obj.material_deform.live = False  # pose first, then one Settle (what a user clicks)
        move(tip, *how)
        activate(obj)
        assert bpy.ops.object.material_deform_settle() == {"FINISHED"}
        obj.material_deform.live = True
        st = session.entry_for(obj, scene).state
        n_ctrl = len(session.entry_for(obj, scene).solver.rest)
        print(
            f"{obj.name}: {n_ctrl} of {len(obj.data.vertices)} vertices controlled, "
            f"{st.get('iterations')} sweeps, last move {st.get('move'):.1e} of the diagonal"
        )
    for x, text in ((-5.0, "tentacle: 2 anchors"), (3.0, "bar: 2 anchors")):
        label(text, (x, -1.0, 5.7))
    for ob in scene.objects:
        if ob.type == "EMPTY":
            ob.empty_display_size = 0.3
    return scene


def main():
    OUT.mkdir(exist_ok=True)
    enable_addon()
    scene = build()
    camera_and_light(scene)
    blend = OUT / "demo.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    engine = render(scene, OUT / "demo.png")
    print(f"DEMO OK: {blend} and {OUT / 'demo.png'} ({engine})")
    scene = build_pyramid()
    camera_and_light(scene)
    blend = OUT / "demo_pyramid.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    png = OUT / "demo_pyramid_blender.png"
    engine = render(scene, png, color_type="MATERIAL")
    print(f"DEMO OK: {blend} and {png} ({engine})")


main()
