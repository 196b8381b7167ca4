"""Screenshots of the Material Deform sidebar panel from a real Blender GUI (run by
scripts/screenshots_blender.sh under Xvfb).

    blender -b --factory-startup --python screenshots_blender.py -- build SCENE.blend
    blender --factory-startup --enable-event-simulate --python-expr ENABLE SCENE.blend \
        --python screenshots_blender.py -- shoot OUT_DIR

``build`` makes a posed bar (stiffness painted, two anchors, bound, top Empty moved). ``shoot``
shows the sidebar at its default width on the Material Deform tab (Blender 3.4 has no API for
the tab: it clicks down the tab column until the panel is drawn), then saves the sidebar with
the mesh selected (addon_panel_mesh.png) and with the top anchor Empty selected
(addon_panel_empty.png).
"""

import functools
import os
import sys

import bpy

print = functools.partial(print, flush=True)  # noqa: A001 (the log is read while it runs)

argv = sys.argv[sys.argv.index("--") + 1 :]
mode, target = argv[0], argv[1]


def build(path):
    sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests", "blender"))
    from helpers import paint, tube, two_end_anchors

    bpy.ops.wm.read_homefile(use_factory_startup=True)  # camera, light and the default UI
    for o in list(bpy.data.objects):
        if o.type == "MESH":
            bpy.data.objects.remove(o)
    bpy.context.view_layer.update()
    obj = tube(rings=21)
    paint(obj, "Stiffness", lambda v: 1.0 if abs(v.co.z) < 0.6 else 0.0)
    assert bpy.ops.mesh.material_deform_stiffness_from_paint() == {"FINISHED"}
    top, _ = two_end_anchors(obj)
    assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
    top.empty.location.x += 1.0
    top.empty.rotation_euler.y = 0.6
    bpy.context.view_layer.update()
    obj.material_deform.anchors[0].name = "Top"
    obj.material_deform.anchors[1].name = "Bottom"
    bpy.ops.wm.save_as_mainfile(filepath=path)


def _view3d():
    win = bpy.context.window_manager.windows[0]
    for area in win.screen.areas:
        if area.type == "VIEW_3D":
            region = next(r for r in area.regions if r.type == "UI")
            return win, area, region
    raise RuntimeError("no 3D viewport")


shown = {"panel": False}


def _patch_panel():
    panel = bpy.types.VIEW3D_PT_material_deform
    draw = panel.draw

    def traced(self, context):
        shown["panel"] = True
        draw(self, context)

    panel.draw = traced


def _crop_save(full, region, out):
    img = bpy.data.images.load(full)
    w, h = img.size
    import numpy as np

    px = np.empty(w * h * 4, np.float32)
    img.pixels.foreach_get(px)
    px = px.reshape(h, w, 4)
    crop = px[region.y : region.y + region.height, region.x : region.x + region.width]
    # keep the rows down to the end of the panels: below them the (black, overlay-free)
    # viewport shows through for good (rows are stored bottom-up)
    lit = crop[::-1, 10, :3].max(axis=1) > 0.02
    for y in range(20, len(lit) - 40):
        if not lit[y : y + 40].any():
            crop = crop[len(lit) - y - 10 :]
            break
    ch, cw = crop.shape[:2]
    res = bpy.data.images.new(os.path.basename(out), cw, ch, alpha=True)
    res.pixels.foreach_set(np.ascontiguousarray(crop).ravel())
    res.filepath_raw = out
    res.file_format = "PNG"
    res.save()
    print(f"saved {out} ({cw}x{ch})")


def shoot(out_dir):
    os.makedirs(out_dir, exist_ok=True)
    _patch_panel()
    mesh = bpy.data.objects["Bar"]
    empty = mesh.material_deform.anchors[0].empty
    steps = []

    from material_deform.bridge import activate as select

    def show_sidebar():
        win, area, region = _view3d()
        space = area.spaces[0]
        space.show_region_ui = True
        # a plain black viewport behind the sidebar, so the shot can end where the panels do
        space.overlay.show_overlays = False
        space.shading.background_type = "VIEWPORT"
        space.shading.background_color = (0.0, 0.0, 0.0)
        select(mesh)
        for p in (
            "VIEW3D_PT_material_deform_stiffness",
            "VIEW3D_PT_material_deform_anchors",
            "VIEW3D_PT_material_deform_deform",
            "VIEW3D_PT_material_deform_bake",
        ):
            getattr(bpy.types, p).bl_options = set()  # (their default: open)
        return None

    tries = {"n": 0}

    def find_tab():
        win, area, region = _view3d()
        if shown["panel"]:
            print("Material Deform tab active, sidebar width", region.width)
            return None
        tries["n"] += 1
        if tries["n"] > 30:
            raise RuntimeError("Material Deform tab not found")
        # click down the tab column at the sidebar's right edge until our panel is drawn
        x = region.x + region.width - 10
        y = region.y + region.height - 20 - 20 * tries["n"]
        win.event_simulate(type="MOUSEMOVE", value="NOTHING", x=x, y=y)
        win.event_simulate(type="LEFTMOUSE", value="PRESS", x=x, y=y)
        win.event_simulate(type="LEFTMOUSE", value="RELEASE", x=x, y=y)
        return 0.3

    def shot(name, obj):
        def run():
            select(obj)
            return None

        def take():
            win, area, region = _view3d()
            full = os.path.join(out_dir, f".{name}_full.png")
            with bpy.context.temp_override(window=win):
                bpy.ops.screen.screenshot(filepath=full)
            _crop_save(full, region, os.path.join(out_dir, f"{name}.png"))
            os.unlink(full)
            return None

        return [run, take]

    steps = [show_sidebar, find_tab, *shot("addon_panel_mesh", mesh)]
    steps += shot("addon_panel_empty", empty)

    def quit_blender():
        bpy.ops.wm.quit_blender()

    steps += [quit_blender]

    def runner():
        while steps:
            step = steps[0]
            wait = step()
            if wait is None:
                steps.pop(0)
                return 0.5  # let the window redraw before the next step
            return wait
        return None

    bpy.app.timers.register(runner, first_interval=1.0)


if mode == "build":
    build(target)
else:
    shoot(target)
