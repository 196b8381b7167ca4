"""Around the mesh: the 3D viewports' shading, status text and redraws, frames and the
depsgraph, file paths, and the Mesh Cache modifier that plays a point-cache bake."""

from __future__ import annotations

import contextlib
import os

import bpy

from ..farm_job import file_name


def _view3d_spaces(context):
    wm = getattr(context, "window_manager", None)
    for win in wm.windows if wm is not None else ():
        for area in win.screen.areas:
            if area.type == "VIEW_3D":
                for space in area.spaces:
                    if space.type == "VIEW_3D":
                        yield space


def viewport_shading(context) -> str:
    """'TYPE COLOR_TYPE' of the first 3D viewport, '' if there is none."""
    for space in _view3d_spaces(context):
        return f"{space.shading.type} {space.shading.color_type}"
    return ""


def set_viewport_shading(context, shading: str) -> int:
    """Set every 3D viewport to 'TYPE COLOR_TYPE'; returns how many were set."""
    kind, _, color = shading.partition(" ")
    n = 0
    for space in _view3d_spaces(context):
        with contextlib.suppress(TypeError, ValueError):
            space.shading.type = kind
            if color:
                space.shading.color_type = color
            n += 1
    return n


def show_attribute_shading(context) -> bool:
    """Switch open 3D viewports to Solid + Attribute colour. False if there is none."""
    return set_viewport_shading(context, "SOLID VERTEX") > 0


def status(context, text) -> None:
    ws = getattr(context, "workspace", None)
    if ws is not None:
        with contextlib.suppress(Exception):
            ws.status_text_set(text)


def redraw(context) -> None:
    """Draw the window now, so the status text set inside a long operator shows before the
    operator returns (Blender only redraws between events). Nothing in background mode."""
    if bpy.app.background or getattr(context, "window", None) is None:
        return
    with contextlib.suppress(Exception):
        bpy.ops.wm.redraw_timer(type="DRAW_WIN_SWAP", iterations=1)


def frame_set(scene, frame) -> None:
    scene.frame_set(frame)


def evaluated_depsgraph_from_scene(scene):
    """Depsgraph of the current view layer (the one frame_set just evaluated)."""
    return bpy.context.evaluated_depsgraph_get()


def abspath(path: str) -> str:
    return bpy.path.abspath(path)


def object_names() -> list[str]:
    """Every object's name in the file (what an object's file name must differ from)."""
    return [o.name for o in bpy.data.objects]


def not_editable(obj) -> str:
    """Why the object's bind cannot be kept in this file ('' if it can): linked from a library
    (read-only here), or a library override, whose mesh keys and add-on settings the file does
    not keep (they are gone on reopen)."""
    for what, idb in (("object", obj), ("mesh", obj.data)):
        if idb.library is not None:
            how = f"linked from '{bpy.path.basename(idb.library.filepath)}'"
        elif getattr(idb, "override_library", None) is not None:
            how = "a library override"
        else:
            continue
        return (
            f"'{obj.name}': its {what} is {how}, so this file cannot keep a bind of it. Make "
            "it local first (Object > Relations > Make Local > Selected Objects and Data), or "
            "bind it in its library file"
        )
    return ""


def mesh_sharers(obj) -> list[str]:
    """Names of the other objects that use this object's mesh (linked duplicates, Alt+D)."""
    mesh = obj.data
    if mesh.users - int(mesh.use_fake_user) <= 1:
        return []
    return [o.name for o in bpy.data.objects if o.data == mesh and o != obj]


def object_file_name(obj) -> str:
    """``<blend name>_<object>``: a file-name stem that no other object, and no other .blend in
    the same folder, gives (farm_job.file_name); 'untitled' before the first save."""
    blend = os.path.splitext(os.path.basename(bpy.data.filepath))[0] or "untitled"
    return f"{blend}_{file_name(obj.name, object_names())}"


def blend_saved() -> bool:
    return bool(bpy.data.filepath)


CACHE_MODIFIER = "Material Deform Cache"


def cache_modifier(obj):
    mod = obj.modifiers.get(CACHE_MODIFIER)
    return mod if mod is not None and mod.type == "MESH_CACHE" else None


def add_cache_modifier(obj, filepath: str, frame_start: int):
    """A Mesh Cache modifier at the top of the stack reading ``filepath`` (.pc2), frame
    ``frame_start`` = the file's first sample; it replaces the shape-key result exactly."""
    mod = cache_modifier(obj) or obj.modifiers.new(CACHE_MODIFIER, "MESH_CACHE")
    mod.cache_format = "PC2"
    mod.filepath = filepath
    mod.play_mode = "SCENE"
    mod.time_mode = "FRAME"
    mod.frame_start = float(frame_start)
    mod.frame_scale = 1.0
    mod.deform_mode = "OVERWRITE"
    mod.interpolation = "LINEAR"
    mod.forward_axis, mod.up_axis = "POS_Y", "POS_Z"  # the file is in the mesh's own axes
    index = list(obj.modifiers).index(mod)
    if index:
        if hasattr(obj.modifiers, "move"):  # 4.0+
            obj.modifiers.move(index, 0)
        else:
            with bpy.context.temp_override(object=obj, active_object=obj):
                bpy.ops.object.modifier_move_to_index(modifier=mod.name, index=0)
    return mod


def remove_cache_modifier(obj) -> bool:
    mod = cache_modifier(obj)
    if mod is None:
        return False
    obj.modifiers.remove(mod)
    return True
