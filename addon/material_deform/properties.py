"""Add-on settings stored on the Object (saved in the .blend)."""

from __future__ import annotations

import math

import bpy
from bpy.props import (
    BoolProperty,
    CollectionProperty,
    EnumProperty,
    FloatProperty,
    FloatVectorProperty,
    IntProperty,
    PointerProperty,
    StringProperty,
)

from . import methods, updates

IDENTITY16 = (1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1)
UNKNOWN_BIND_FRAME = -(2**31)  # session.twist.UNKNOWN_FRAME


def _settings_changed(self, context):
    """A setting the bind depends on changed: compare the object with its bound state again
    (so changing a setting back makes the bind valid again)."""
    updates.bind_setting(self, context)


def _is_empty(_self, obj):
    return obj.type == "EMPTY"


class MaterialDeformAnchor(bpy.types.PropertyGroup):
    name: StringProperty(name="Name", default="Anchor")
    vertex_group: StringProperty(
        name="Vertex Group",
        description="Anchor faces: polygons whose vertices are all in it",
        update=_settings_changed,
    )
    empty: PointerProperty(
        name="Empty",
        type=bpy.types.Object,
        poll=_is_empty,
        description="Controller of the anchor: its faces follow this Empty",
        update=_settings_changed,
    )
    mode: EnumProperty(
        name="Mode",
        description="How the anchor faces follow their Empty",
        items=(
            (
                "POSITION",
                "Follow Empty",
                "The anchor faces follow the Empty's full transform (location, rotation, scale)",
                "PIVOT_BOUNDBOX",
                0,
            ),
            (
                "ROTATION",
                "Rotation + Scale",
                "Only the Empty's rotation and scale are prescribed; the anchor may drift "
                "(the paper's mode)",
                "CON_ROTLIKE",
                1,
            ),
            (
                "FRAME",
                "Frame",
                "Pose space: the faces follow the Empty and give the frame in which the pose is "
                "measured (turning the whole rig keeps the pose); one anchor, on the trunk",
                "ORIENTATION_LOCAL",
                2,
            ),
        ),
        default="POSITION",
        update=_settings_changed,
    )
    # world matrix of the Empty at bind time (its bind pose), row-major
    bind_matrix: FloatVectorProperty(size=16, default=IDENTITY16, options={"HIDDEN"})
    # the scene frame of the bind pose: turns are counted along the animation from there
    # (UNKNOWN_BIND_FRAME: bound by an older version; the scene's start frame is used)
    bind_frame: IntProperty(default=UNKNOWN_BIND_FRAME, options={"HIDDEN"})
    # the Empty the bind pose belongs to (None: not bound yet, or bound by an older version)
    bound_empty: PointerProperty(type=bpy.types.Object, options={"HIDDEN"})


_SPAN_MIN, _SPAN_MAX = 0.5, 8.0


def _get_softest(self) -> float:
    return 10.0**-self.stiffness_span


def _set_softest(self, value) -> None:
    span = -math.log10(max(float(value), 1e-30))
    self.stiffness_span = min(max(span, _SPAN_MIN), _SPAN_MAX)


_FIELDS = (
    ("SHEAR", "Shear", "Per-face shear stiffness (what Stiffness from Paint makes from the paint)"),
    (
        "BEND",
        "Bend",
        "Per-edge bending stiffness averaged at each vertex (where a learned joint shows)",
    ),
)
_AXES = tuple(
    (f"BEND_{c}", f"Bend {c}", f"Bending stiffness about the {c.lower()} axis (anisotropic)")
    for c in "XYZ"
)
# numbers fixed, so a saved choice keeps its meaning when the list changes
_FIELD_ITEMS = tuple((*f, i) for i, f in enumerate(_FIELDS))
_FIELD_ITEMS_ANISO = _FIELD_ITEMS + tuple((*f, 2 + i) for i, f in enumerate(_AXES))


def _field_items(self, _context):
    # module-level tuples: Blender keeps pointers to the strings of dynamic items
    return _FIELD_ITEMS_ANISO if self.anisotropic else _FIELD_ITEMS


class MaterialDeformSettings(bpy.types.PropertyGroup):
    method: EnumProperty(
        name="Method",
        description="How the mesh follows the anchors (every method uses the same anchors)",
        items=methods.enum_items(),
        default=methods.all_methods()[0].key,
        update=_settings_changed,
    )
    anchors: CollectionProperty(type=MaterialDeformAnchor)
    active_anchor_index: IntProperty(name="Active Anchor", default=0, min=0)

    stiffness_source: EnumProperty(
        name="Paint Source",
        description="Where the stiffness is painted",
        items=(
            ("VERTEX_GROUP", "Vertex Group", "Weight Paint: weight 0 = flexible, 1 = stiff"),
            ("COLOR_ATTRIBUTE", "Color Attribute", "Vertex Paint: black = flexible, white = stiff"),
        ),
        default="VERTEX_GROUP",
    )
    stiffness_group: StringProperty(
        name="Vertex Group",
        default="Stiffness",
        description="Vertex group painted in Weight Paint: 0 = flexible, 1 = stiff",
    )
    color_attribute: StringProperty(
        name="Color Attribute",
        default="Stiffness",
        description="Color attribute painted in Vertex Paint: black = flexible, white = stiff",
    )
    stiffness_span: FloatProperty(
        name="Stiffness Span",
        description="Decades between paint 0 and paint 1: paint 0 maps to 10^-span, paint 1 to 1 "
        "(the panel shows it as Softest = 10^-span)",
        default=3.0,
        min=_SPAN_MIN,
        max=_SPAN_MAX,
    )
    stiffness_softest: FloatProperty(
        name="Softest",
        description="Stiffness of paint 0, relative to paint 1 (stiff = 1). Paint in between is "
        "spaced evenly on a log scale: with 0.001, paint 0.5 gives about 0.03",
        get=_get_softest,
        set=_set_softest,
        min=10.0**-_SPAN_MAX,
        max=10.0**-_SPAN_MIN,
        soft_min=1e-6,
        precision=3,
        step=1,
    )
    display_field: EnumProperty(
        name="Show",
        description="Which stored stiffness Show colours (blue = flexible, red = stiff)",
        items=_field_items,
    )
    # what Show replaced, restored by Hide: the active colour attribute and the viewport
    # shading ("TYPE COLOR_TYPE")
    display_prev_color: StringProperty(options={"HIDDEN"})
    display_prev_shading: StringProperty(options={"HIDDEN"})
    anisotropic: BoolProperty(
        name="Anisotropic",
        description="One bending stiffness per rotation axis, painted in the groups "
        "'<group> X', '<group> Y', '<group> Z' (or the R, G, B channels of the color attribute)",
        default=False,
        update=_settings_changed,
    )
    axes_empty: PointerProperty(
        name="Axes",
        type=bpy.types.Object,
        poll=_is_empty,
        description="Empty whose orientation gives the anisotropy axes (default: the object's "
        "local axes). Parent it to the mesh object so it moves with it",
        update=_settings_changed,
    )
    region_group: StringProperty(
        name="Deform Only",
        description="Vertex group of the region of interest: only polygons whose vertices are "
        "all in it deform, its border stays at rest, the rest is untouched (empty = whole mesh)",
        update=_settings_changed,
    )
    # anisotropy axes frozen at bind (row-major 3x3): the solver is rebuilt from these after
    # loading a file, when the axes Empty's world matrix is not evaluated yet
    bind_axes: FloatVectorProperty(size=9, default=(1, 0, 0, 0, 1, 0, 0, 0, 1), options={"HIDDEN"})
    learn_filter: StringProperty(
        name="Keys",
        description="Learn from Shape Keys and the Pose space examples use the unmuted shape "
        "keys whose name contains this text (empty = all)",
        update=_settings_changed,
    )
    learn_region: IntProperty(
        name="Neighbourhood",
        description="0: learn the bending of every edge on its own (the paper). Above 0: judge "
        "each place by how much the face rotations spread over a neighbourhood this many "
        "smoothing passes wide, which finds broad soft parts such as a torso (about 2000 suits "
        "a 15k-face character; isotropic only)",
        default=0,
        min=0,
        soft_max=10000,
    )

    bound: BoolProperty(name="Bound", default=False, options={"HIDDEN"})
    live: BoolProperty(
        name="Live", default=True, description="Update the deformation when anchor Empties move"
    )
    created_basis: BoolProperty(default=False, options={"HIDDEN"})
    rebind_reason: StringProperty(options={"HIDDEN"})
    fp_topology: StringProperty(options={"HIDDEN"})
    fp_anchors: StringProperty(options={"HIDDEN"})
    fp_stiffness: StringProperty(options={"HIDDEN"})
    fp_method: StringProperty(options={"HIDDEN"})
    # the output shape key's name (followed when the user renames it)
    output_key_name: StringProperty(default="Material Deform", options={"HIDDEN"})
    # world matrix of the mesh object at bind, row-major; all zeros: bound by an older version
    obj_bind_matrix: FloatVectorProperty(size=16, default=(0.0,) * 16, options={"HIDDEN"})

    bake_start: IntProperty(name="Start", default=1, description="First frame to bake")
    bake_end: IntProperty(name="End", default=50, description="Last frame to bake")
    bake_output: EnumProperty(
        name="Bake To",
        description="Where Bake writes the frames",
        items=(
            (
                "POINT_CACHE",
                "Point Cache",
                "One .pc2 file read by a Mesh Cache modifier: light, works anywhere in the "
                "modifier stack and exports to Alembic / USD",
            ),
            (
                "SHAPE_KEYS",
                "Shape Keys",
                "One keyframed shape key per frame, stored in the .blend",
            ),
        ),
        default="POINT_CACHE",
    )
    bake_cache_path: StringProperty(
        name="File",
        description="Point cache file (.pc2). Empty: '//<object name>.pc2' next to the .blend",
        subtype="FILE_PATH",
        options={"PATH_SUPPORTS_BLEND_RELATIVE"} if bpy.app.version >= (4, 5, 0) else set(),
    )


# The methods registered when the add-on registers, not when this module is imported, make the
# Method menu (its annotation is a string, evaluated by register_class) and the settings groups,
# so a method registered later (a script, a test) only needs the add-on registered again.
classes: tuple = ()  # what register() registered, unregistered in reverse
_groups: list[str] = []  # the settings groups register() added to MaterialDeformSettings


def register():
    global classes
    with_settings = [m for m in methods.all_methods() if m.settings_class is not None]
    for m in with_settings:  # obj.material_deform.<settings_name>
        MaterialDeformSettings.__annotations__[m.settings_name] = PointerProperty(
            type=m.settings_class
        )
    _groups[:] = [m.settings_name for m in with_settings]
    classes = (
        MaterialDeformAnchor,
        *(m.settings_class for m in with_settings),
        MaterialDeformSettings,
    )
    for cls in classes:
        bpy.utils.register_class(cls)
    bpy.types.Object.material_deform = PointerProperty(type=MaterialDeformSettings)


def unregister():
    del bpy.types.Object.material_deform
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
    for name in _groups:
        del MaterialDeformSettings.__annotations__[name]
    _groups.clear()
