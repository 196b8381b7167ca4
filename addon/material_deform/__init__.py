"""Material Deform: material-aware mesh deformation (Popa, Julius, Sheffer 2006) for Blender.

Paint stiffness, add anchors driven by Empties, Bind, then move the Empties: the result goes to
a "Material Deform" shape key over the untouched rest shape.

The bpy modules are imported in register(), so the pure helpers (``stiffness_map``,
``anchor_math``) stay importable and testable without Blender.
"""

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
    from . import handlers, operators, properties, ui

    return (properties, operators, ui, handlers)


def register():
    for m in _modules():
        m.register()


def unregister():
    for m in reversed(_modules()):
        m.unregister()
