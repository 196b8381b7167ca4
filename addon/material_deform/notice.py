"""What the add-on registers instead of itself where its native core cannot run
(``platform_check``): the reason, in the add-on's preferences and in its sidebar tab."""

from __future__ import annotations

import bpy

# The unregister function of the classes register() made (they carry the message, so they are
# built per call), or None.
_unregister = None


def register(package: str, message: str) -> None:
    global _unregister
    lines = ["Material Deform cannot run in this Blender:", *_wrap(message, 60)]

    def draw(self, _context):
        for i, line in enumerate(lines):
            self.layout.label(text=line, icon="ERROR" if i == 0 else "BLANK1")

    prefs = type(
        "MATERIAL_DEFORM_AP_unsupported",
        (bpy.types.AddonPreferences,),
        {"bl_idname": package, "draw": draw},
    )
    panel = type(
        "VIEW3D_PT_material_deform_unsupported",
        (bpy.types.Panel,),
        {
            "bl_space_type": "VIEW_3D",
            "bl_region_type": "UI",
            "bl_category": "Material Deform",
            "bl_label": "Material Deform",
            "draw": draw,
        },
    )
    register_classes, _unregister = bpy.utils.register_classes_factory((prefs, panel))
    register_classes()


def unregister() -> None:
    global _unregister
    if _unregister is not None:
        _unregister()
        _unregister = None


def _wrap(text: str, width: int) -> list[str]:
    out, line = [], ""
    for word in text.split():
        if line and len(line) + 1 + len(word) > width:
            out.append(line)
            line = word
        else:
            line = f"{line} {word}" if line else word
    return out + ([line] if line else [])
