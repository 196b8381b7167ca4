"""Point-cache bakes on a render farm, the parts without bpy: frame ranges, the chunk files, their
merge into one .pc2, and the job bundle (docs/farm.md). Importable without Blender
(``scripts/farm_bake.py``, ``tests/python``).

A farm bake runs one background Blender per chunk of frames (``farm.py``); each writes
``<output>/chunks/<object>.<first>-<last>.pc2`` (``<object>``: :func:`file_name`). The merge
step writes ``<output>/<object>.pc2``
only when the chunks cover the frame range exactly once with one point count: never a partial
cache.
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil

import numpy as np

from .pointcache import PC2Writer, read_pc2, temp_name

TEMPLATE = "material_deform_bake.yaml"  # the OpenJD job template, in farm/ of the repository
TASK = "material_deform_farm_task.py"  # its tasks' script (embedded in it), for other farms
CHUNKS = "chunks"  # the chunk folder inside the output folder
PREFIX = "Material Deform farm:"  # starts every line the tasks print about the bake
_HERE = os.path.dirname(os.path.abspath(__file__))


class FarmError(Exception):
    """Something the job cannot do; the message is for the job's log (one sentence)."""


def parse_frames(expr: str) -> list[int]:
    """The frames of an OpenJD integer range expression: ``"7"``, ``"1-12"``, ``"1-12:3"`` or a
    comma list of those (what a task's chunk parameter expands to), in the order given."""
    frames: list[int] = []
    for part in str(expr).split(","):
        m = re.fullmatch(r"\s*(-?\d+)\s*(?:-\s*(-?\d+)\s*(?::\s*(\d+)\s*)?)?", part)
        if m is None:
            raise FarmError(f"'{expr}' is not a frame range (e.g. 1-12)")
        a = int(m[1])
        b = a if m[2] is None else int(m[2])
        step = int(m[3] or 1)
        if b < a or step < 1:
            raise FarmError(f"'{expr}' is not a frame range (e.g. 1-12)")
        frames.extend(range(a, b + 1, step))
    return frames


def contiguous(frames: list[int]) -> tuple[int, int]:
    """(first, last) of frames that follow one another (a point cache holds one sample per
    frame, consecutive)."""
    if not frames or list(frames) != list(range(frames[0], frames[0] + len(frames))):
        raise FarmError(f"frames {frames}: a point cache needs consecutive frames")
    return frames[0], frames[-1]


# Names Windows keeps for devices, with any extension ("CON.pc2" opens the console).
_RESERVED = {"CON", "PRN", "AUX", "NUL", *(f"{d}{i}" for d in ("COM", "LPT") for i in range(1, 10))}


def file_name(name: str, others=()) -> str:
    """The file-name stem for the object called ``name``, which no other object name gives on
    any system. Letters of any script, digits, '-', '_' and '.' are kept, everything else becomes
    '_'. When that changed the name, or the name is one Windows reserves, ends in '.', or equals
    one of ``others`` (the other objects' names) but for case (Windows and macOS ignore case),
    the first 8 hex digits of the name's SHA-1 follow: 'Arm.L', 'Arm L' and 'Arm_L' give
    'Arm.L', 'Arm_L-<hash>' and 'Arm_L'."""
    kept = "".join(c if c.isalnum() or c in "-_." else "_" for c in name) or "_"
    folded = name.casefold()
    if (
        kept != name
        or kept.endswith(".")
        or kept.split(".")[0].upper() in _RESERVED
        or any(o != name and o.casefold() == folded for o in others)
    ):
        kept += "-" + hashlib.sha1(name.encode("utf-8")).hexdigest()[:8]
    return kept


def chunk_path(output: str, obj_name: str, first: int, last: int, others=()) -> str:
    name = f"{file_name(obj_name, others)}.{first:04d}-{last:04d}.pc2"
    return os.path.join(output, CHUNKS, name)


def merged_path(output: str, obj_name: str, others=()) -> str:
    return os.path.join(output, f"{file_name(obj_name, others)}.pc2")


def baked_blend_path(output: str, blend: str, obj_name: str, others=()) -> str:
    """The saved copy of the .blend that reads the merged cache (one per baked object)."""
    stem = os.path.splitext(os.path.basename(blend))[0]
    return os.path.join(output, f"{stem}_{file_name(obj_name, others)}_baked.blend")


def record_path(chunk: str) -> str:
    """Where a chunk's record of what it was baked from is kept (next to it)."""
    return chunk + ".json"


def write_record(chunk: str, baked_from: str) -> None:
    """Keep ``baked_from`` (bake.baked_from of the object when the chunk was baked) next to the
    chunk, atomically."""
    path = record_path(chunk)
    tmp = temp_name(path)
    with open(tmp, "w", encoding="utf-8") as f:
        json.dump({"baked_from": baked_from}, f)
    os.replace(tmp, path)


def read_record(chunk: str) -> str | None:
    try:
        with open(record_path(chunk), encoding="utf-8") as f:
            return str(json.load(f)["baked_from"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def find_chunks(output: str, obj_name: str, others=()) -> list[tuple[int, int, str]]:
    """(first, last, path) of every chunk file of the object in the output folder, sorted.
    ``others``: the other objects' names, as for :func:`file_name`."""
    folder = os.path.join(output, CHUNKS)
    prefix = file_name(obj_name, others) + "."
    found = []
    for name in os.listdir(folder) if os.path.isdir(folder) else []:
        # digits only after the prefix: 'Bar.001.0001-0004.pc2' is not a chunk of 'Bar'
        m = re.fullmatch(r"(-?\d+)-(-?\d+)\.pc2", name[len(prefix) :])
        if name.startswith(prefix) and m:
            found.append((int(m[1]), int(m[2]), os.path.join(folder, name)))
    return sorted(found)


def _ranges(frames) -> str:
    """'1-4, 9, 11-12' for a sorted list of frames."""
    out, run = [], []
    for f in frames:
        if run and f != run[-1] + 1:
            out.append(run)
            run = []
        run.append(f)
    if run:
        out.append(run)
    return ", ".join(f"{r[0]}" if len(r) == 1 else f"{r[0]}-{r[-1]}" for r in out)


def plan_merge(
    output: str,
    obj_name: str,
    first: int,
    last: int,
    points: int,
    others=(),
    baked_from: str | None = None,
) -> list[str]:
    """The chunk files that make the frames first..last, in order. FarmError (naming the files
    and frames) when a frame has no chunk, two chunks overlap, a chunk's header does not match
    its name or the point count, or (given ``baked_from``, what the file holds now) a chunk was
    baked from something else: the merge then writes nothing."""
    found = find_chunks(output, obj_name, others)
    chunks = [c for c in found if c[1] >= first and c[0] <= last]
    where = os.path.join(output, CHUNKS)
    covered = np.zeros(last - first + 1, np.int64)
    for a, b, _p in chunks:
        covered[max(a, first) - first : min(b, last) - first + 1] += 1
    missing = [first + i for i in np.flatnonzero(covered == 0)]
    if missing:
        raise FarmError(
            f"no chunk holds frame(s) {_ranges(missing)} of '{obj_name}' in {where}: a chunk "
            "task failed or has not run (run it again); nothing merged"
        )
    for (_a0, b0, p0), (a1, _b1, p1) in zip(chunks, chunks[1:], strict=False):
        if a1 <= b0:  # sorted by first frame: any overlap shows between neighbours
            raise FarmError(
                f"chunks {os.path.basename(p0)} and {os.path.basename(p1)} overlap (left from "
                "an earlier job with other chunks? delete the old ones); nothing merged"
            )
    if chunks[0][0] < first or chunks[-1][1] > last:
        extra = chunks[0][2] if chunks[0][0] < first else chunks[-1][2]
        raise FarmError(
            f"chunk {os.path.basename(extra)} reaches beyond frames {first}-{last} (left from "
            "an earlier job? delete it); nothing merged"
        )
    for a, b, path in chunks:
        try:
            start, rate, data = read_pc2(path)
        except (OSError, ValueError) as exc:
            raise FarmError(f"cannot read chunk {path}: {exc}; nothing merged") from exc
        if start != a or rate != 1.0 or len(data) != b - a + 1:
            raise FarmError(
                f"chunk {os.path.basename(path)} holds {len(data)} sample(s) from frame {start:g} "
                f"(rate {rate:g}), not frames {a}-{b}; nothing merged"
            )
        if data.shape[1] != points:
            raise FarmError(
                f"chunk {os.path.basename(path)} has {data.shape[1]} points, '{obj_name}' has "
                f"{points} vertices (the mesh changed since the chunk was baked?); nothing merged"
            )
    if baked_from is not None:
        other = [os.path.basename(p) for _a, _b, p in chunks if read_record(p) != baked_from]
        if other:
            raise FarmError(
                f"chunk(s) {', '.join(other)} were baked from another version of '{obj_name}' "
                "(its bind, method settings or the anchors' animation changed in the saved "
                "file since, or they have no record of it): bake them again; nothing merged"
            )
    return [p for _a, _b, p in chunks]


def merge(
    output: str,
    obj_name: str,
    first: int,
    last: int,
    points: int,
    others=(),
    baked_from: str | None = None,
) -> str:
    """Check the chunks (:func:`plan_merge`) and write them as one .pc2 (atomically: an existing
    merged cache stays as it was on any error). Returns its path."""
    paths = plan_merge(output, obj_name, first, last, points, others, baked_from)
    out = merged_path(output, obj_name, others)
    with PC2Writer(out, points, last - first + 1, first) as w:
        for path in paths:
            for x in read_pc2(path)[2]:
                w.add(x)
    return out


# --- the job bundle -------------------------------------------------------------------------------


def farm_file(name: str) -> str:
    """A file of farm/ (the template, the task script): next to this module in a built add-on,
    farm/ in the source tree."""
    for path in (
        os.path.join(_HERE, name),
        os.path.join(_HERE, os.pardir, os.pardir, "farm", name),
    ):
        if os.path.isfile(path):
            return os.path.normpath(path)
    raise FarmError(f"{name} is missing from the add-on")


def template_path() -> str:
    return farm_file(TEMPLATE)


def job_parameters(
    blend: str,
    obj_name: str,
    first: int,
    last: int,
    chunk_size: int,
    output: str,
    blender: str = "blender",
    addon_zip: str = "",
) -> dict:
    """The template's parameter values (absolute paths)."""
    if last < first:
        raise FarmError(f"frame range {first}-{last} is empty")
    if not 1 <= chunk_size <= 150:  # Deadline Cloud's limit for a chunk
        raise FarmError(f"chunk size {chunk_size}: must be 1 to 150")
    params = {
        "BlendFile": os.path.abspath(blend),
        "Object": obj_name,
        "FrameStart": int(first),
        "FrameEnd": int(last),
        "ChunkSize": int(chunk_size),
        "OutputFolder": os.path.abspath(output),
        "Blender": blender,
    }
    if addon_zip:
        params["AddonZip"] = os.path.abspath(addon_zip)
    return params


def write_bundle(folder: str, params: dict) -> dict:
    """A job bundle in ``folder``: ``template.yaml`` (the job template), ``parameter_values.json``
    (what ``deadline bundle submit`` reads), ``openjd_params.json`` (what ``openjd run -p
    file://...`` reads) and the tasks' script (for other farms, docs/farm.md). Returns the
    commands that run it (:func:`commands`)."""
    os.makedirs(folder, exist_ok=True)
    shutil.copyfile(template_path(), os.path.join(folder, "template.yaml"))
    shutil.copyfile(farm_file(TASK), os.path.join(folder, TASK))
    values = [{"name": k, "value": v} for k, v in params.items()]
    with open(os.path.join(folder, "parameter_values.json"), "w", encoding="utf-8") as f:
        json.dump({"parameterValues": values}, f, indent=2)
    with open(os.path.join(folder, "openjd_params.json"), "w", encoding="utf-8") as f:
        json.dump(params, f, indent=2)
    cmds = commands(folder, params)
    with open(os.path.join(folder, "README.txt"), "w", encoding="utf-8") as f:
        f.write(
            f"Material Deform farm bake of '{params['Object']}', frames "
            f"{params['FrameStart']}-{params['FrameEnd']} (docs/farm.md).\n\n"
            f"Run it on this machine (openjd-cli from PyPI):\n  {cmds['local']}\n\n"
            "Submit it to AWS Deadline Cloud (the deadline CLI from PyPI):\n"
            f"  {cmds['deadline']}\n\n"
            f"Another farm runs {TASK} in Blender, once per chunk of frames, then once to\n"
            f"merge:\n  {cmds['chunk']}\n  {cmds['merge']}\n"
        )
    return cmds


def _quote(s: str) -> str:
    return s if re.fullmatch(r"[\w@%+=:,./-]+", s) else "'" + s.replace("'", "'\\''") + "'"


def commands(folder: str, params: dict | None = None) -> dict:
    """The shell commands that run the bundle in ``folder``: ``local`` (openjd run, every chunk
    then the merge, one after the other), ``deadline`` (submit to the default queue) and, with
    the ``params``, ``chunk`` (the first chunk's task; its frames are the ones to change) and
    ``merge`` (the last task) as any farm runs them."""
    folder = os.path.abspath(folder)
    template = os.path.join(folder, "template.yaml")
    out = {
        "local": f"openjd run {_quote(template)} --step Merge --run-dependencies "
        f"-p {_quote('file://' + os.path.join(folder, 'openjd_params.json'))}",
        "deadline": f"deadline bundle submit {_quote(folder)}",
    }
    if params:
        first, last = params["FrameStart"], params["FrameEnd"]
        chunk = f"{first}-{min(first + params['ChunkSize'] - 1, last)}"
        for task, frames in (("chunk", chunk), ("merge", f"{first}-{last}")):
            args = [params["Blender"], "-b", "--python-exit-code", "1", "--python"]
            args += [os.path.join(folder, TASK), "--", task, params["BlendFile"]]
            args += [params["Object"], frames, params["OutputFolder"]]
            args += [params["AddonZip"]] if params.get("AddonZip") else []
            out[task] = " ".join(_quote(str(a)) for a in args)
    return out
