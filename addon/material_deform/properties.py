"""Add-on settings stored on the Object (saved in the .blend)."""

from __future__ import annotations

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

from . import methods


def _anchor_changed(self, _context):
    from . import session  # late: session imports the core lazily, keep registration light

    session.mark_stale(self.id_data, "Anchors changed since bind - click Bind again")


IDENTITY16 = (1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1)


def _material_changed(self, _context):
    from . import session

    session.mark_stale(self.id_data, "Anisotropy or region changed since bind - click Bind again")


def _is_empty(_self, obj):
    return obj.type == "EMPTY"


class MaterialDeformAnchor(bpy.types.PropertyGroup):
    name: StringProperty(name="Name", default="Anchor")
    vertex_group: StringProperty(
        name="Vertex Group",
        description="Anchor faces: polygons whose vertices are all in it",
        update=_anchor_changed,
    )
    empty: PointerProperty(
        name="Empty",
        type=bpy.types.Object,
        poll=_is_empty,
        description="Controller of the anchor",
        update=_anchor_changed,
    )
    mode: EnumProperty(
        name="Mode",
        items=(
            ("POSITION", "Follow Empty", "Anchor faces follow the Empty's full transform"),
            (
                "ROTATION",
                "Rotation + Scale",
                "Only the Empty's rotation and scale are prescribed; the anchor may drift "
                "(the paper's mode)",
            ),
        ),
        default="POSITION",
        update=_anchor_changed,
    )
    # world matrix of the Empty at bind time, row-major
    bind_matrix: FloatVectorProperty(size=16, default=IDENTITY16, options={"HIDDEN"})


def _method_changed(self, _context):
    from . import session

    session.mark_stale(self.id_data, "Method changed since bind - click Bind again")


class MaterialDeformSettings(bpy.types.PropertyGroup):
    method: EnumProperty(
        name="Method",
        description="How the mesh follows the anchors (every method uses the same anchors)",
        items=methods.enum_items(),
        default=methods.all_methods()[0].key,
        update=_method_changed,
    )
    anchors: CollectionProperty(type=MaterialDeformAnchor)
    active_anchor_index: IntProperty(name="Active Anchor", default=0, min=0)

    stiffness_source: EnumProperty(
        name="Paint Source",
        items=(
            ("VERTEX_GROUP", "Vertex Group", "Weight Paint: weight 0 = flexible, 1 = stiff"),
            ("COLOR_ATTRIBUTE", "Color Attribute", "Vertex Paint: black = flexible, white = stiff"),
        ),
        default="VERTEX_GROUP",
    )
    stiffness_group: StringProperty(name="Vertex Group", default="Stiffness")
    color_attribute: StringProperty(name="Color Attribute", default="Stiffness")
    stiffness_span: FloatProperty(
        name="Span (decades)",
        description="Paint 0 maps to 10^-span, paint 1 to 1 (log scale)",
        default=3.0,
        min=0.5,
        max=8.0,
    )
    anisotropic: BoolProperty(
        name="Anisotropic",
        description="One bending stiffness per rotation axis, painted in the groups "
        "'<group> X', '<group> Y', '<group> Z' (or the R, G, B channels of the color attribute)",
        default=False,
        update=_material_changed,
    )
    axes_empty: PointerProperty(
        name="Axes",
        type=bpy.types.Object,
        poll=_is_empty,
        description="Empty whose orientation gives the anisotropy axes (default: the object's "
        "local axes). Parent it to the mesh object so it moves with it",
        update=_material_changed,
    )
    region_group: StringProperty(
        name="Region",
        description="Vertex group of the region of interest: only polygons whose vertices are "
        "all in it deform, its border stays at rest, the rest is untouched (empty = whole mesh)",
        update=_material_changed,
    )
    # anisotropy axes frozen at bind (row-major 3x3): the solver is rebuilt from these after
    # loading a file, when the axes Empty's world matrix is not evaluated yet
    bind_axes: FloatVectorProperty(size=9, default=(1, 0, 0, 0, 1, 0, 0, 0, 1), options={"HIDDEN"})
    learn_filter: StringProperty(
        name="Keys",
        description="Learn from Shape Keys uses the unmuted shape keys whose name contains this "
        "text (empty = all)",
    )
    learn_region: IntProperty(
        name="Region",
        description="0: the paper's per-edge bending. Above 0: region-level bending over this "
        "many smoothing passes, which finds broad soft parts such as a torso (about 2000 suits a "
        "15k-face character; isotropic only; see docs/learn.md)",
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

    bake_start: IntProperty(name="Start", default=1)
    bake_end: IntProperty(name="End", default=50)


# Each method's own settings group becomes obj.material_deform.<settings_name>.
for _m in methods.all_methods():
    if _m.settings_class is not None:
        MaterialDeformSettings.__annotations__[_m.settings_name] = PointerProperty(
            type=_m.settings_class
        )

classes = (
    MaterialDeformAnchor,
    *(m.settings_class for m in methods.all_methods() if m.settings_class is not None),
    MaterialDeformSettings,
)
_register_classes, _unregister_classes = bpy.utils.register_classes_factory(classes)


def register():
    _register_classes()
    bpy.types.Object.material_deform = PointerProperty(type=MaterialDeformSettings)


def unregister():
    del bpy.types.Object.material_deform
    _unregister_classes()
