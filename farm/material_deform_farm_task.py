# Material Deform farm task (docs/farm.md), run inside Blender:
#   blender -b --python-exit-code 1 --python material_deform_farm_task.py -- \
#       chunk|merge FILE.blend OBJECT FRAMES OUTPUT_FOLDER [ADDON_ZIP]
# Finds and enables the Material Deform add-on (installed, or the legacy zip shipped with the
# job), then hands over to its farm module. Without the add-on it fails at once, saying so in
# its first line: never a cache of undeformed frames. The same text is embedded in
# material_deform_bake.yaml (tests/python/test_farm_job.py keeps them equal).
import importlib
import os
import sys

import bpy

addon_utils = importlib.import_module("addon_utils")  # with the bpy module: after bpy


def fail(message):
    print(f"Material Deform farm: ERROR: {message}", flush=True)
    sys.exit(1)


def shipped_addon(path):
    """The add-on shipped with the job: a legacy zip (unpacked to a temporary folder) or a
    folder holding material_deform/; put on sys.path."""
    import atexit
    import shutil
    import tempfile
    import zipfile

    where = path
    if not os.path.isdir(path):
        where = tempfile.mkdtemp(prefix="material_deform_addon_")
        atexit.register(shutil.rmtree, where, True)
        try:
            with zipfile.ZipFile(path) as z:
                if "blender_manifest.toml" in z.namelist():
                    fail(f"{path} is the extension: ship the legacy zip")
                z.extractall(where)
        except (OSError, zipfile.BadZipFile) as exc:
            fail(f"cannot unpack the shipped add-on {path}: {exc}")
    if not os.path.isfile(os.path.join(where, "material_deform", "__init__.py")):
        fail(f"{path} holds no material_deform add-on folder")
    sys.path.insert(0, where)
    return "material_deform"


def installed_addon():
    """The installed add-on's module: 'material_deform' (legacy) or
    'bl_ext.<repository>.material_deform' (extension, Blender 4.2+)."""
    for m in addon_utils.modules():
        if m.__name__.rsplit(".", 1)[-1] == "material_deform":
            return m.__name__
    fail(
        f"the Material Deform add-on is not installed in this Blender "
        f"({bpy.app.version_string}, {bpy.app.binary_path or sys.executable}): install it "
        "on the workers, or ship the legacy zip with the job (parameter AddonZip); nothing baked"
    )


def main():
    argv = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else sys.argv[1:]
    if len(argv) not in (5, 6):
        fail(f"expected: chunk|merge FILE.blend OBJECT FRAMES OUTPUT [ADDON_ZIP], got {argv}")
    shipped = argv[5] if len(argv) == 6 else ""
    name = shipped_addon(shipped) if shipped else installed_addon()
    mod = sys.modules.get(name) if addon_utils.check(name)[1] else None
    mod = mod or addon_utils.enable(name)
    if mod is None:
        fail(f"the add-on '{name}' failed to enable (see the lines above)")
    if getattr(mod, "unsupported", None):
        fail(f"the add-on cannot run in this Blender: {mod.unsupported}")
    version = ".".join(map(str, getattr(mod, "bl_info", {}).get("version", ())))
    where = os.path.dirname(mod.__file__)
    print(f"Material Deform farm: add-on {version} ({where}), Blender {bpy.app.version_string}")
    sys.stdout.flush()
    return importlib.import_module(name + ".farm").main(argv[:5])


sys.exit(main())
