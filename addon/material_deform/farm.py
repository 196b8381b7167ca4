"""Point-cache bakes on a render farm (docs/farm.md), the parts inside Blender: what the OpenJD
job's tasks run (:func:`main`) and the operator that writes the job for the active object.

A chunk task bakes its frames exactly as a local Bake does (``bake.write_point_cache``, one
frame-only start per frame: ``bake.frame_start``), so the merged chunks equal a single-process
bake. The file logic without bpy (ranges, chunk files, merge, bundle) is in ``farm_job``.
"""

from __future__ import annotations

import contextlib
import os
import time
import traceback

import bpy
from bpy.props import IntProperty, StringProperty

from . import bake, bridge, farm_job, session
from .farm_job import PREFIX, FarmError
from .model import BindError, settings
from .operators import _BLEND_RELATIVE, _ObjectOperator
from .pointcache import temp_name

# --- the tasks ----------------------------------------------------------------------------------


def _say(text: str) -> None:
    print(f"{PREFIX} {text}", flush=True)


def _open(blend: str, obj_name: str):
    """Load the saved .blend; (object, scene) of the bound, up-to-date mesh ``obj_name``."""
    if not os.path.isfile(blend):
        raise FarmError(f"no .blend at {blend}")
    bpy.ops.wm.open_mainfile(filepath=blend, load_ui=False)
    obj = bpy.data.objects.get(obj_name)
    if obj is None or obj.type != "MESH":
        raise FarmError(f"{blend} has no mesh object '{obj_name}'")
    scenes = [bpy.context.scene, *bpy.data.scenes]
    scene = next((s for s in scenes if s is not None and obj.name in s.objects), None)
    if scene is None:
        raise FarmError(f"'{obj_name}' is in no scene of {blend}")
    if not settings(obj).bound:
        raise FarmError(f"'{obj_name}' is not bound in {blend}: bind it and save the file")
    if session.full_check(obj, scene):
        raise FarmError(f"'{obj_name}': {session.stale_reason(obj)}, then save the file")
    return obj, scene


def _frames(expr: str) -> tuple[list[int], int, int]:
    frames = farm_job.parse_frames(expr)
    first, last = farm_job.contiguous(frames)
    return frames, first, last


def run_chunk(blend: str, obj_name: str, frames_expr: str, output: str) -> str:
    """Bake the frames of one chunk into ``<output>/chunks/<object>.<first>-<last>.pc2``
    (replacing that chunk if it exists; atomically). Returns its path."""
    frames, first, last = _frames(frames_expr)
    obj, scene = _open(blend, obj_name)
    baked_from = bake.baked_from(obj)
    path = farm_job.chunk_path(output, obj.name, first, last, bridge.object_names())
    os.makedirs(os.path.dirname(path), exist_ok=True)
    _say(f"baking '{obj.name}' ({settings(obj).method}) frames {first}-{last} into {path}")
    unsettled: list = []
    t0 = time.perf_counter()

    def progress(_fraction, text):  # a line per frame in the task's log
        _say(text.removeprefix("Material Deform: "))

    bake.write_point_cache(obj, scene, frames, path, progress, unsettled)
    farm_job.write_record(path, baked_from)  # what the merge checks the chunk against
    _say(f"chunk {first}-{last} done in {time.perf_counter() - t0:.2f} s")
    if unsettled:
        _say("WARNING: " + bake.unsettled_warning(unsettled, len(frames)))
    return path


def run_merge(blend: str, obj_name: str, frames_expr: str, output: str) -> tuple[str, str]:
    """Merge the chunks into ``<output>/<object>.pc2`` and save a copy of the .blend in the
    output folder whose Mesh Cache modifier reads it (Live off). Writes nothing unless every
    frame has exactly one chunk of the right size (:func:`farm_job.plan_merge`). Returns (the
    merged cache, the saved copy)."""
    _frames_list, first, last = _frames(frames_expr)
    obj, scene = _open(blend, obj_name)
    others = bridge.object_names()
    points = len(obj.data.vertices)
    merged = farm_job.merge(output, obj.name, first, last, points, others, bake.baked_from(obj))
    _say(f"merged frames {first}-{last} of '{obj.name}' into {merged}")
    copy = farm_job.baked_blend_path(output, blend, obj.name, others)
    # Relative to the file as it is now; saving with relative_remap makes it '//<name>.pc2',
    # next to the copy, so the output folder can move (or come back from a farm) as a whole.
    bake.use_point_cache(obj, scene, bpy.path.relpath(merged), first)
    # renamed when complete, so an earlier copy stays until then; a name of this process's own,
    # so that two merges at once (a re-run while the first still runs) do not meet
    tmp = temp_name(copy, ".blend")
    try:
        bpy.ops.wm.save_as_mainfile(filepath=tmp, relative_remap=True)
        os.replace(tmp, copy)
    except (RuntimeError, OSError) as exc:
        for leftover in (tmp, tmp + "1"):  # and the backup Blender makes of a file it replaces
            with contextlib.suppress(OSError):
                os.unlink(leftover)
        reason = exc.strerror if isinstance(exc, OSError) else str(exc).strip()
        raise FarmError(f"cannot save {copy}: {reason}") from None
    _say(f"saved {copy}: its Mesh Cache modifier reads {bridge.cache_modifier(obj).filepath}")
    return merged, copy


def main(argv) -> int:
    """The job's task: ``argv`` = [chunk | merge, .blend, object, frames, output folder].
    Exit status 0, or 1 with one line saying why (nothing partial is left behind)."""
    try:
        command, blend, obj_name, frames, output = argv
        if command == "chunk":
            run_chunk(blend, obj_name, frames, output)
        elif command == "merge":
            run_merge(blend, obj_name, frames, output)
        else:
            raise FarmError(f"unknown task '{command}' (chunk or merge)")
    except (FarmError, BindError, ValueError) as exc:
        _say(f"ERROR: {exc}")
        return 1
    except OSError as exc:  # the output folder: missing, read-only, full, a file in the way
        what = f"cannot write {exc.filename}" if exc.filename else "cannot write the output"
        _say(f"ERROR: {what}: {exc.strerror or exc} (the output folder must be writable)")
        return 1
    except Exception as exc:  # a bug: the traceback for the report, then the one line
        traceback.print_exc()
        _say(f"ERROR: {type(exc).__name__}: {exc}")
        return 1
    return 0


# --- the operator -------------------------------------------------------------------------------


def unsaved_changes() -> bool:
    """True when the open .blend differs from the saved one, which is what the farm bakes.
    Only the GUI can tell: in a background run ``bpy.data.is_dirty`` stays set after saving
    (Blender 3.4), so a script there must save before writing the job."""
    return bool(bpy.data.is_dirty) and not bpy.app.background


class OBJECT_OT_material_deform_farm_job(_ObjectOperator, bpy.types.Operator):
    """Write an Open Job Description job that bakes this object's point cache on a render farm,
    in chunks of frames, then merges them (run it here with openjd, or submit it to AWS
    Deadline Cloud); the .blend must be saved"""

    bl_idname = "object.material_deform_farm_job"
    bl_label = "Write Farm Bake Job"

    directory: StringProperty(
        name="Output Folder",
        description="Where the job bundle (job/), the chunks, the merged .pc2 and the baked copy "
        "of the .blend go (empty: 'farm_<object>' next to the .blend)",
        subtype="DIR_PATH",
        options={"SKIP_SAVE"} | _BLEND_RELATIVE,
    )
    chunk_size: IntProperty(
        name="Frames per Task",
        description="Frames each farm task bakes (each task starts Blender and loads the file)",
        default=10,
        min=1,
        max=150,
    )
    frame_start: IntProperty(name="Start", description="First frame", options={"SKIP_SAVE"})
    frame_end: IntProperty(name="End", description="Last frame", options={"SKIP_SAVE"})
    blender: StringProperty(
        name="Blender",
        description="The Blender executable on the workers",
        default="blender",
    )
    addon_zip: StringProperty(
        name="Ship Add-on",
        description="Optional: the legacy add-on zip to send with the job, for workers without "
        "the add-on installed",
        subtype="FILE_PATH",
        options={"SKIP_SAVE"} | _BLEND_RELATIVE,
    )

    def invoke(self, context, _event):
        return context.window_manager.invoke_props_dialog(self)

    def run(self, context, obj):
        try:
            folder, cmds, stale = self.write(context, obj)
        except (FarmError, OSError) as exc:
            raise BindError(str(exc)) from exc
        context.window_manager.clipboard = cmds["local"]
        print(f"{PREFIX} job for '{obj.name}' in {folder}\n  {cmds['local']}\n  {cmds['deadline']}")
        self.report(
            {"INFO"},
            f"Farm job written to {folder}. Run it here: {cmds['local']} (copied to the "
            f"clipboard); or submit it to Deadline Cloud: {cmds['deadline']}",
        )
        if stale:
            self.report(
                {"WARNING"},
                f"{len(stale)} chunk file(s) of an earlier bake of '{obj.name}' are in the "
                "output folder: delete them, or the merge refuses the overlapping chunks",
            )
        return {"FINISHED"}

    def write(self, context, obj):
        """Check the object and write the bundle; (bundle folder, commands, old chunks)."""
        s = settings(obj)
        if not bpy.data.filepath:
            raise BindError("Save the .blend first: the farm bakes the saved file")
        if unsaved_changes():
            raise BindError("The .blend has unsaved changes: save it first (the farm bakes it)")
        if not s.bound:
            raise BindError(f"'{obj.name}' is not bound: click Bind")
        if session.full_check(obj, context.scene):
            raise BindError(session.stale_reason(obj))
        props = self.properties
        if not props.is_property_set("frame_start"):
            self.frame_start = s.bake_start
        if not props.is_property_set("frame_end"):
            self.frame_end = s.bake_end
        if not self.directory:
            self.directory = f"//farm_{bridge.object_file_name(obj)}"
        output = os.path.normpath(bridge.abspath(self.directory))
        params = farm_job.job_parameters(
            bpy.data.filepath,
            obj.name,
            self.frame_start,
            self.frame_end,
            self.chunk_size,
            output,
            self.blender,
            bridge.abspath(self.addon_zip) if self.addon_zip else "",
        )
        folder = os.path.join(output, "job")
        cmds = farm_job.write_bundle(folder, params)
        return folder, cmds, farm_job.find_chunks(output, obj.name, bridge.object_names())


classes = (OBJECT_OT_material_deform_farm_job,)
register, unregister = bpy.utils.register_classes_factory(classes)
