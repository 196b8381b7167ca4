"""Material Deform: material-aware mesh deformation (Popa, Julius, Sheffer 2006) for Blender.

Paint stiffness, add anchors driven by Empties, Bind, then move the Empties: the result goes to
a "Material Deform" shape key over the untouched rest shape.

The bpy modules are imported in register(), so the pure helpers (``stiffness_map``,
``anchor_math``, ``platform_check``) stay importable and testable without Blender.
"""

from __future__ import annotations

bl_info = {
    "name": "Material Deform",
    "author": "Material Deform developers",
    "version": (0, 1, 0),
    "blender": (3, 4, 0),
    "location": "3D Viewport > Sidebar > Material Deform",
    "description": "Material-aware mesh deformation driven by anchor Empties",
    "category": "Mesh",
}


def _modules():
    from . import farm, handlers, operators, properties, ui

    return (properties, operators, farm, ui, handlers)


# Why the bundled native core cannot run in this Blender, or None (set by register()).
unsupported: str | None = None


def register():
    global unsupported
    from . import platform_check

    unsupported = platform_check.problem_here()
    if unsupported:  # say why, and register nothing that would need the core
        from . import notice

        print(f"Material Deform cannot run in this Blender: {unsupported}")
        notice.register(__package__, unsupported)
        return
    for m in _modules():
        m.register()


def unregister():
    if unsupported:
        from . import notice

        notice.unregister()
        return
    for m in reversed(_modules()):
        m.unregister()
