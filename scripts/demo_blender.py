"""Demo scenes, built by script:

- a tapered tentacle whose stiffness follows its girth (paper Fig. 1/10) and a bar with a stiff
  middle (Fig. 4), each deformed twice by the same Empty moves: uniform material (left) vs
  material-aware (right): out/demo.blend, out/demo.png;
- Edge-based: a sheet pinned at two corners hanging under gravity, Stretch (lambda) from
  membrane to cloth, side by side: out/demo_edge.blend, out/demo_edge.png;
- Pose space: a tentacle with two example shape keys (curled up with a bulging muscle, bent
  sideways), posed through the add-on by dragging its tip Empty between and beyond them:
  out/demo_pose_space.blend, out/demo_pose_space_addon.png;
- Pyramid coordinates: a tentacle and a bar posed with the anchor faces' vertices as the only
  control vertices, no painting: out/demo_pyramid.blend, out/demo_pyramid_blender.png;
- a 540-degree twist keyed on the top Empty of a striped tube, Blender's Laplacian Deform
  beside each of the four methods: out/demo_twist.blend, out/demo_twist.png.

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
import numpy as np  # noqa: E402
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
    from material_deform.bridge import activate  # once the add-on is enabled

    activate(obj)


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


# --- pose space -------------------------------------------------------------------------------

PS_LENGTH, PS_RINGS, PS_SIDES = 5.0, 48, 16


def ps_bend(v, angle, azimuth, bulge=0.0):
    """The tentacle (along +z from 0) bent by ``angle`` towards the horizontal direction at
    ``azimuth`` (0 = +x), each z = const section moved rigidly; ``bulge`` swells a muscle on the
    inner side around a third of the length."""
    v = np.asarray(v, np.float64)
    c, s_ = math.cos(azimuth), math.sin(azimuth)
    u = v[:, 0] * c + v[:, 1] * s_  # along the bend direction
    w = -v[:, 0] * s_ + v[:, 1] * c
    t = v[:, 2] / PS_LENGTH
    if bulge:
        muscle = bulge * np.exp(-(((t - 0.35) / 0.12) ** 2)) * np.clip(u, 0, None)
        u = u * (1 + muscle)
        w = w * (1 + 0.5 * muscle)
    rho = PS_LENGTH / angle
    a = v[:, 2] / rho
    u2 = rho - (rho - u) * np.cos(a)
    z2 = (rho - u) * np.sin(a)
    return np.stack([u2 * c - w * s_, u2 * s_ + w * c, z2], axis=1)


def ps_tentacle(name, location):
    obj = tube(name, lambda t: 0.45 - 0.3 * t, PS_LENGTH, PS_RINGS, PS_SIDES, location)
    v = np.array([p.co[:] for p in obj.data.vertices])
    obj.shape_key_add(name="Basis", from_mix=False)
    for key, coords in (
        ("Curl + muscle", ps_bend(v, 0.5 * math.pi, 0.0, bulge=1.6)),
        ("Bend sideways", ps_bend(v, 0.5 * math.pi, 0.5 * math.pi)),
    ):
        kb = obj.shape_key_add(name=key, from_mix=False)
        kb.data.foreach_set("co", coords.astype(np.float32).ravel())
        kb.value = 0.0
    return obj, v


def ps_girth_colours(obj, x, v):
    """Colour = girth over rest girth (a bulge shows bright), per vertex, as a colour
    attribute Workbench shows."""
    ring = np.arange(len(v)) // PS_SIDES
    g = np.ones(len(v))
    for r in range(PS_RINGS):
        idx = np.flatnonzero(ring == r)
        c = x[idx].mean(0)
        g[idx] = np.linalg.norm(x[idx] - c, axis=1) / np.linalg.norm(v[idx, :2], axis=1)
    k = np.clip((g - 1.0) / 0.2, 0, 1)[:, None]
    rgba = np.hstack([(1 - k) * [0.3, 0.45, 0.8] + k * [1.0, 0.4, 0.05], np.ones_like(k)])
    me = obj.data
    attr = me.color_attributes.new("Girth", "FLOAT_COLOR", "POINT")
    attr.data.foreach_set("color", rgba.astype(np.float32).ravel())
    me.color_attributes.active_color = attr


def ps_pose_tip(obj, tip, v, target):
    """Move the tip Empty so the tip faces sit where ``target`` puts them (a rigid fit)."""
    from material_deform import anchor_math as am
    from material_deform import bridge

    idx = np.flatnonzero(v[:, 2] > PS_LENGTH - 1e-4)
    k = am.rigid_fit(v[idx], target[idx])
    m_obj = np.array(obj.matrix_world)
    e_bind = np.array(tuple(tip.bind_matrix)).reshape(4, 4)
    bridge.set_world_matrix(tip.empty, m_obj @ k @ np.linalg.inv(m_obj) @ e_bind)
    bpy.context.view_layer.update()


def build_pose_space():
    from material_deform import bridge, session
    from material_deform.methods import pose_space

    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    shots = [
        ("example: curl + muscle", None, "Curl + muscle"),
        ("example: bend sideways", None, "Bend sideways"),
        ("between: half curl", (0.25 * math.pi, 0.0), None),
        ("between: curl + side", (0.5 * math.pi, 0.25 * math.pi), None),
        ("beyond: curled further", (0.85 * math.pi, 0.0), None),
    ]
    for i, (text, pose, key) in enumerate(shots):
        x0 = -8.0 + 4.0 * i
        obj, v = ps_tentacle(f"Tentacle {i + 1}", (x0, 0, 0))
        if key is not None:  # an example as the user made it: the shape key shown
            obj.data.shape_keys.key_blocks[key].value = 1.0
            x = bridge.shape_key_positions(obj, key)
            label(text, (x0 + 0.8, 0.0, 5.6))
        else:
            add_anchor(obj, lambda p: p.center.z < 1e-4)
            tip = add_anchor(obj, lambda p: p.center.z > PS_LENGTH - 1e-4)
            s = obj.material_deform
            s.anchors[0].mode = "FRAME"  # the base: the pose is measured in its frame
            s.method = "POSE_SPACE"
            activate(obj)
            assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
            ps_pose_tip(obj, tip, v, ps_bend(v, pose[0], pose[1]))
            x = bridge.shape_key_positions(obj, s.output_key_name)
            w = pose_space.weights_readout(session.cached_entry(obj))
            shown = " ".join(f"{wi:.2f}" for _n, wi in w)
            print(f"pose space demo, {text}: weights (rest, curl, side) = {shown}")
            label(text, (x0 + 0.8, 0.0, 5.6))
            label(f"w = {shown}", (x0 + 0.8, 0.0, 5.1))
        ps_girth_colours(obj, x, v)
    for ob in scene.objects:
        if ob.type == "EMPTY":
            ob.empty_display_size = 0.25
    return scene


def camera_and_light_pose_space(scene):
    """A three-quarter view from the front left, so the sideways bend shows; labels face it."""
    camera_and_light(scene)
    cam = scene.camera
    cam.data.ortho_scale = 22.0
    target = Vector((1.6, 0.0, 2.2))
    direction = Vector((0.25, 0.9, -0.2)).normalized()  # the camera looks this way
    cam.location = target - 30.0 * direction
    cam.rotation_euler = direction.to_track_quat("-Z", "Y").to_euler()
    scene.render.resolution_x, scene.render.resolution_y = 1800, 760
    scene.world.color = (0.18, 0.18, 0.2)  # the white labels read on a dark ground
    for ob in scene.objects:
        if ob.type == "FONT":
            ob.data.size = 0.36
            ob.rotation_euler = cam.rotation_euler


SHEET_STRETCH = ((2e-4, "membrane"), (1e-3, ""), (1e-2, ""), (1e-1, "cloth"))


def grid_sheet(name, n, location):
    """An n x n quad sheet, 1 x 1, in the z = 0 plane of its object."""
    verts = [(i / n, j / n, 0.0) for j in range(n + 1) for i in range(n + 1)]
    faces = [
        (j * (n + 1) + i, j * (n + 1) + i + 1, (j + 1) * (n + 1) + i + 1, (j + 1) * (n + 1) + i)
        for j in range(n)
        for i in range(n)
    ]
    me = bpy.data.meshes.new(name)
    me.from_pydata(verts, [], faces)
    obj = bpy.data.objects.new(name, me)
    obj.location = location
    bpy.context.scene.collection.objects.link(obj)
    return obj


def sheet_color(obj):
    """Colour by edge strain (blue: rest length, red: +50 %), from the settled shape key."""
    me = obj.data
    rest = [v.co.copy() for v in me.vertices]
    key = me.shape_keys.key_blocks["Material Deform"].data
    strain = [0.0] * len(me.vertices)
    count = [0] * len(me.vertices)
    for e in me.edges:
        a, b = e.vertices
        s = (key[a].co - key[b].co).length / (rest[a] - rest[b]).length - 1.0
        for v in (a, b):
            strain[v] += s
            count[v] += 1
    attr = me.color_attributes.new("md_strain", "FLOAT_COLOR", "POINT")
    for i, (s, c) in enumerate(zip(strain, count, strict=True)):
        t = max(0.0, min(1.0, s / max(c, 1) / 0.5))
        attr.data[i].color = (0.25 + 0.7 * t, 0.35 * (1 - t) + 0.2, 0.9 * (1 - t) + 0.1, 1.0)
    me.color_attributes.active_color = attr
    mat = bpy.data.materials.new(f"{obj.name} strain")
    mat.use_nodes = True
    nt = mat.node_tree
    node = nt.nodes.new("ShaderNodeAttribute")
    node.attribute_name = "md_strain"
    nt.links.new(node.outputs["Color"], nt.nodes.get("Principled BSDF").inputs["Base Color"])
    me.materials.append(mat)


def build_sheets():
    """A 40 x 40 sheet pinned at the two corner faces of its back side, the pins moved 30 %
    closer together, settled under the same gravity for each Stretch (bend 1)."""
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    n = 40
    h = 1.0 - 1.0 / n
    for i, (lam, name) in enumerate(SHEET_STRETCH):
        obj = grid_sheet(f"Sheet lambda {lam:g}", n, (1.6 * i, 0.0, 0.0))
        left = add_anchor(obj, lambda p: p.center.x < 1.0 / n and p.center.y > h)
        right = add_anchor(obj, lambda p: p.center.x > h and p.center.y > h)
        s = obj.material_deform
        s.method = "EDGE"
        e = s.edge
        e.stretch, e.bend = lam, 1.0
        e.gravity_strength = 1.2  # scene gravity direction (down)
        e.settle_iterations, e.tolerance = 20000, 1e-6
        activate(obj)
        assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
        s.live = False  # settle once below, not per Empty move
        left.empty.location.x += 0.15
        right.empty.location.x -= 0.15
        bpy.context.view_layer.update()
        activate(obj)
        assert bpy.ops.object.material_deform_settle() == {"FINISHED"}
        sheet_color(obj)
        label(f"lambda {lam:g}" + (f" ({name})" if name else ""), (1.6 * i + 0.5, 1.0, 0.25))
    for ob in scene.objects:
        if ob.type == "EMPTY":
            ob.empty_display_size = 0.08
        if ob.type == "FONT":
            ob.data.size = 0.16
    camera_and_light(scene)  # then framed on the sheets
    cam = scene.camera
    cam.data.ortho_scale = 6.8
    cam.location = (2.9, -9.0, -0.3)
    cam.rotation_euler = (math.radians(88), 0, 0)
    scene.render.resolution_x, scene.render.resolution_y = 1600, 560
    return scene


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
            f"{st.get('iterations')} Newton iterations, last step {st.get('move'):.1e} of the "
            f"diagonal, {'converged' if st.get('converged') else 'NOT converged'}"
        )
    for x, text in ((-5.0, "tentacle: 2 anchors"), (3.0, "bar: 2 anchors")):
        label(text, (x, -1.0, 5.7))
    for ob in scene.objects:
        if ob.type == "EMPTY":
            ob.empty_display_size = 0.3
    return scene


# --- turns past half a turn -------------------------------------------------------------------


# Methods shown beside Laplacian Deform: those that carry an anchor's turns past half a turn
# (Edge-based, Pyramid and Pose space join once their solves start from the unwrapped turns).
def _edge_twist_settings(obj):
    # the edge method keeps a twist only on slender parts at a moderate stretch (docs/edge.md,
    # twists past half a turn): this tube (30 radii long) holds 540 degrees at stretch 0.3,
    # converged, and unwinds a whole turn at 1
    obj.material_deform.edge.stretch = 0.3


def _pose_space_twist_example(obj):
    # pose space blends example shapes: one key besides the rest, the tube twisted by 90
    # degrees linearly along it (a blend of uniform twists stays a uniform twist)
    co = np.empty(3 * len(obj.data.vertices), np.float32)
    obj.data.vertices.foreach_get("co", co)
    v = co.reshape(-1, 3).astype(np.float64)
    a = 0.5 * math.pi * v[:, 2] / TWIST_LENGTH
    c, s = np.cos(a), np.sin(a)
    twisted = np.stack([c * v[:, 0] - s * v[:, 1], s * v[:, 0] + c * v[:, 1], v[:, 2]], 1)
    obj.shape_key_add(name="Basis")
    obj.shape_key_add(name="Twist").data.foreach_set("co", twisted.astype(np.float32).ravel())


# (method, column label, settings applied before Bind)
TWIST_METHODS = (
    ("MATERIAL", "Material-aware", None),
    ("EDGE", "Edge-based", _edge_twist_settings),
    ("POSE_SPACE", "Pose space", _pose_space_twist_example),
    ("PYRAMID", "Pyramid (unwinds)", None),
)
TWIST_DEGREES, TWIST_FRAME = 540, 19  # keyed from 0 at frame 1, linearly: 30 degrees a frame
TWIST_LENGTH, TWIST_RADIUS, TWIST_RINGS, TWIST_SIDES = 5.0, 0.15, 61, 24
TWIST_SPACING = 2.0  # between the columns' axes


def striped_tube(name, x):
    """The tube of md.shapes.tube's proportions (10 radii long) along +Z, with two lengthwise
    stripes (a colour attribute Workbench shows): a twist draws them as helices."""
    obj = tube(name, lambda t: TWIST_RADIUS, TWIST_LENGTH, TWIST_RINGS, TWIST_SIDES, (x, 0.0, 0.0))
    side = np.arange(len(obj.data.vertices)) % TWIST_SIDES
    # two stripes, one facing the camera (-y) at rest
    stripe = ((side - 3 * TWIST_SIDES // 4 + 1) % (TWIST_SIDES // 2)) < TWIST_SIDES // 8
    rgba = np.where(stripe[:, None], [0.85, 0.25, 0.1, 1.0], [0.92, 0.92, 0.88, 1.0])
    me = obj.data
    attr = me.color_attributes.new("Stripes", "FLOAT_COLOR", "POINT")
    attr.data.foreach_set("color", rgba.astype(np.float32).ravel())
    me.color_attributes.active_color = attr
    return obj


def key_twist(empty):
    """The Empty's turn about the tube's axis keyed from 0 (frame 1) to TWIST_DEGREES (linear)."""
    empty.rotation_mode = "XYZ"
    empty.rotation_euler = (0.0, 0.0, 0.0)
    empty.keyframe_insert("rotation_euler", index=2, frame=1)
    empty.rotation_euler.z = math.radians(TWIST_DEGREES)
    empty.keyframe_insert("rotation_euler", index=2, frame=TWIST_FRAME)
    from material_deform import bridge

    for fc in bridge.action_fcurves(empty.animation_data):
        for k in fc.keyframe_points:
            k.interpolation = "LINEAR"


def laplacian_twist(x):
    """Laplacian Deform with both end rings as anchors, the top one on a Hook whose Empty is
    keyed like the add-on's (Blender's own setup, bench/bench_blender.py)."""
    obj = striped_tube("Laplacian Deform", x)
    me = obj.data
    z = np.array([v.co.z for v in me.vertices])
    bottom = np.flatnonzero(z < 1e-4).tolist()
    top = np.flatnonzero(z > TWIST_LENGTH - 1e-4).tolist()
    obj.vertex_groups.new(name="Anchors").add(bottom + top, 1.0, "REPLACE")
    hook_empty = bpy.data.objects.new("Laplacian hook", None)
    bpy.context.scene.collection.objects.link(hook_empty)
    hook_empty.location = (x, 0.0, TWIST_LENGTH)
    bpy.context.view_layer.update()
    hook = obj.modifiers.new("Hook", "HOOK")
    hook.object = hook_empty
    hook.vertex_indices_set(top)
    hook.matrix_inverse = hook_empty.matrix_world.inverted()
    lap = obj.modifiers.new("LaplacianDeform", "LAPLACIANDEFORM")
    lap.vertex_group = "Anchors"
    activate(obj)
    bpy.context.view_layer.update()
    with bpy.context.temp_override(object=obj, active_object=obj):
        bpy.ops.object.laplaciandeform_bind(modifier=lap.name)
    bpy.context.view_layer.update()
    key_twist(hook_empty)
    return obj


def build_twist():
    """Laplacian Deform and each method of TWIST_METHODS, the top of each tube keyed to turn by
    TWIST_DEGREES, shown at the frame it gets there."""
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    scene.frame_set(1)
    columns = [("Laplacian Deform", None, None)] + [(t, k, f) for k, t, f in TWIST_METHODS]
    for i, (text, method, setup) in enumerate(columns):
        x = TWIST_SPACING * i
        if method is None:
            laplacian_twist(x)
        else:
            obj = striped_tube(text, x)
            obj.material_deform.method = method
            if setup is not None:
                setup(obj)
            add_anchor(obj, lambda p: p.center.z < 1e-4)
            top = add_anchor(obj, lambda p: p.center.z > TWIST_LENGTH - 1e-4)
            top.empty.rotation_euler = (0.0, 0.0, 0.0)  # upright: Z along the tube's axis
            bpy.context.view_layer.update()
            activate(obj)
            assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
            key_twist(obj.material_deform.anchors[1].empty)
        label(text, (x, -1.0, TWIST_LENGTH + 0.55))
    scene.frame_set(TWIST_FRAME)
    middle = 0.5 * TWIST_SPACING * (len(columns) - 1)
    label(f"top turned by {TWIST_DEGREES} degrees", (middle, -1.0, -0.75))
    for ob in scene.objects:
        if ob.type == "EMPTY":
            ob.empty_display_size = 0.35
        if ob.type == "FONT":
            ob.data.size = 0.24
    camera_and_light(scene)
    scene.world.color = (0.18, 0.18, 0.2)  # the white labels read on a dark ground
    cam = scene.camera
    width = TWIST_SPACING * len(columns) + 1.2
    cam.data.ortho_scale = max(width, TWIST_LENGTH + 2.4)
    cam.location = (middle, -20.0, TWIST_LENGTH / 2)
    scene.render.resolution_x = round(1000 * width / cam.data.ortho_scale)
    scene.render.resolution_y = round(1000 * (TWIST_LENGTH + 2.4) / cam.data.ortho_scale)
    return scene


def save_and_render(scene, blend_name, png_name, **render_options):
    """Save the current file as out/<blend_name> and render the scene to out/<png_name>."""
    blend = OUT / blend_name
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    png = OUT / png_name
    engine = render(scene, png, **render_options)
    print(f"DEMO OK: {blend} and {png} ({engine})")


def main():
    OUT.mkdir(exist_ok=True)
    enable_addon()
    scene = build()
    camera_and_light(scene)
    save_and_render(scene, "demo.blend", "demo.png")

    save_and_render(build_sheets(), "demo_edge.blend", "demo_edge.png")

    scene = build_pose_space()
    camera_and_light_pose_space(scene)
    save_and_render(scene, "demo_pose_space.blend", "demo_pose_space_addon.png")

    scene = build_pyramid()
    camera_and_light(scene)
    save_and_render(scene, "demo_pyramid.blend", "demo_pyramid_blender.png", color_type="MATERIAL")

    save_and_render(build_twist(), "demo_twist.blend", "demo_twist.png")


main()
