"""Install a built add-on zip into a throw-away user directory, enable it and deform a bar.

Run in a fresh process (the test_install tests do that):
    blender -b --factory-startup --python-exit-code 1 --python install_smoke.py -- ZIP [MODE]
    python install_smoke.py ZIP [MODE]            # with the PyPI bpy module
The zip kind is taken from its contents: blender_manifest.toml at the root = extension.
``unsupported``: the zip's core is tagged for another platform; the add-on must enable without
an error, say why it cannot run, and register none of its operators. ``refused``: an extension
whose manifest lists other platforms; Blender must refuse to install it.
"""

import sys
import zipfile

import bpy

argv = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else sys.argv[1:]
path = argv[0]
mode = argv[1] if len(argv) > 1 else "works"
assert mode in ("works", "unsupported", "refused"), mode
with zipfile.ZipFile(path) as z:
    is_extension = "blender_manifest.toml" in z.namelist()

if is_extension:
    bpy.ops.extensions.package_install_files(
        filepath=path, repo="user_default", enable_on_install=True
    )
    module = "bl_ext.user_default.material_deform"
    if mode == "refused":
        assert module not in bpy.context.preferences.addons, "installed on a platform not listed"
        print("INSTALL SMOKE OK", bpy.app.version_string, "refused")
        sys.exit(0)
else:
    bpy.ops.preferences.addon_install(filepath=path, overwrite=True)
    module = "material_deform"
    import addon_utils

    assert addon_utils.enable(module, default_set=True) is not None, "enable failed"
assert module in bpy.context.preferences.addons, f"{module} not enabled"

import importlib  # noqa: E402

if mode == "unsupported":
    pkg = importlib.import_module(module)
    assert pkg.unsupported and "built for CPython" in pkg.unsupported, pkg.unsupported
    assert not hasattr(bpy.types, "OBJECT_OT_material_deform_bind"), "operators registered"
    assert hasattr(bpy.types, "VIEW3D_PT_material_deform_unsupported"), "no notice panel"
    assert bpy.context.preferences.addons[module].preferences is not None, "no notice prefs"
    import addon_utils  # noqa: E402

    addon_utils.disable(module, default_set=True)
    assert not hasattr(bpy.types, "VIEW3D_PT_material_deform_unsupported"), "not unregistered"
    print("INSTALL SMOKE OK", bpy.app.version_string, "unsupported:", pkg.unsupported)
    sys.exit(0)
assert hasattr(bpy.types, "OBJECT_OT_material_deform_bind")
# register() checked the platform against the bundled wheel's tags (both zip kinds carry them)
platform_check = importlib.import_module(module + ".platform_check")
tags = platform_check.wheel_tags(platform_check.HERE)
assert tags and importlib.import_module(module).unsupported is None, tags
print("bundled core tags:", tags)

core = importlib.import_module(module + ".core")
md = core.load()
print("matdeform from", md.__file__)
assert "material_deform" in md.__file__ or "extensions" in md.__file__, md.__file__

bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
bpy.ops.mesh.primitive_cylinder_add(vertices=12, depth=4, radius=0.5, end_fill_type="NGON")
obj = bpy.context.object
bridge = importlib.import_module(module + ".bridge")
for pick in (lambda p: p.center.z > 1.99, lambda p: p.center.z < -1.99):
    mask = [bool(pick(p)) for p in obj.data.polygons]
    bpy.ops.object.mode_set(mode="EDIT")
    bridge.select_polygons_edit(obj, mask)
    assert bpy.ops.mesh.material_deform_add_anchor() == {"FINISHED"}
    bpy.ops.object.mode_set(mode="OBJECT")
assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
top = obj.material_deform.anchors[0].empty
top.location.x += 1.0
bpy.context.view_layer.update()
kb = obj.data.shape_keys.key_blocks["Material Deform"]
moved = [kb.data[i].co.x - obj.data.vertices[i].co.x for i in range(len(kb.data))]
assert abs(max(moved) - 1.0) < 1e-5 and abs(min(moved)) < 1e-5, (max(moved), min(moved))
print("INSTALL SMOKE OK", bpy.app.version_string, "extension" if is_extension else "legacy")
