"""The farm bake's job template and its files, without Blender: `openjd check` accepts the
template, its chunks are what the tasks expect, the merge refuses every partial cache and writes
the chunks in order, and the submit helper's bundle is what openjd and Deadline Cloud read.
(The tasks themselves run in Blender: tests/blender/test_farm.py.)"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import pathlib
import re
import signal
import subprocess
import sys

import numpy as np
import pytest
import yaml
from openjd.model import (
    StepParameterSpaceIterator,
    create_job,
    decode_job_template,
    preprocess_job_parameters,
)

ROOT = pathlib.Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "addon"))

from material_deform import farm_job, pointcache  # noqa: E402
from material_deform.farm_job import FarmError  # noqa: E402
from material_deform.pointcache import PC2Writer, read_pc2  # noqa: E402

TEMPLATE = ROOT / "farm" / "material_deform_bake.yaml"
OPENJD = [sys.executable, "-m", "openjd"]


def job(params: dict, template=TEMPLATE):
    t = decode_job_template(
        template=yaml.safe_load(template.read_text()), supported_extensions=["TASK_CHUNKING"]
    )
    values = preprocess_job_parameters(
        job_template=t,
        job_parameter_values={k: str(v) for k, v in params.items()},
        job_template_dir=template.parent.resolve(),
        current_working_dir=pathlib.Path.cwd(),
    )
    return create_job(job_template=t, job_parameter_values=values)


def params(tmp_path, first=1, last=12, size=4, **kw):
    return farm_job.job_parameters(
        str(tmp_path / "scene.blend"), "Bar", first, last, size, str(tmp_path / "out"), **kw
    )


def test_openjd_check_accepts_the_template():
    out = subprocess.run([*OPENJD, "check", str(TEMPLATE)], capture_output=True, text=True)
    assert out.returncode == 0 and "passes validation" in out.stdout, out.stdout + out.stderr


def test_the_embedded_task_script_is_farm_task_py():
    """Both steps run the task script that other farms run from farm/ (and ruff checks)."""
    t = yaml.safe_load(TEMPLATE.read_text())
    script = (ROOT / "farm" / farm_job.TASK).read_text()
    for step in t["steps"]:
        (f,) = step["script"]["embeddedFiles"]
        assert f["filename"] == farm_job.TASK and f["data"] == script


def test_openjd_check_fails_on_a_broken_template(tmp_path):
    """The check above can fail: a step that depends on a step that does not exist."""
    bad = tmp_path / "bad.yaml"
    bad.write_text(TEMPLATE.read_text().replace("dependsOn: BakeChunks", "dependsOn: Bake"))
    out = subprocess.run([*OPENJD, "check", str(bad)], capture_output=True, text=True)
    assert out.returncode != 0


@pytest.mark.parametrize(
    ("first", "last", "size", "want"),
    [
        (1, 12, 4, ["1-4", "5-8", "9-12"]),
        (1, 10, 4, ["1-4", "5-7", "8-10"]),  # openjd balances the chunks
        (-2, 1, 10, ["-2-1"]),
        (7, 7, 3, ["7-7"]),
    ],
)
def test_chunks_cover_the_frame_range_once_in_contiguous_runs(tmp_path, first, last, size, want):
    j = job(params(tmp_path, first, last, size))
    bake, merge = j.steps
    assert [s.name for s in j.steps] == ["BakeChunks", "Merge"]
    assert [d.dependsOn for d in merge.dependencies] == ["BakeChunks"]
    chunks = [t["Frames"].value for t in StepParameterSpaceIterator(space=bake.parameterSpace)]
    assert chunks == want
    frames = [f for c in chunks for f in farm_job.parse_frames(c)]
    assert frames == list(range(first, last + 1))


def test_the_tasks_get_the_arguments_the_add_on_reads(tmp_path):
    """chunk|merge, .blend, object, frames, output folder, shipped add-on (farm.main)."""
    p = params(tmp_path, addon_zip=str(tmp_path / "md.zip"))
    bake, merge = job(p).steps
    for step, cmd, frames in ((bake, "chunk", "{{Task.Param.Frames}}"), (merge, "merge", None)):
        run = step.script.actions.onRun
        assert run.command == "{{Param.Blender}}"
        args = run.args[run.args.index("--") + 1 :]
        assert args[0] == cmd and len(args) == 6
        assert args[1:] == [
            "{{Param.BlendFile}}",
            "{{Param.Object}}",
            frames or "{{Param.FrameStart}}-{{Param.FrameEnd}}",
            "{{Param.OutputFolder}}",
            "{{Param.AddonZip}}",
        ]
        assert run.args[:5] == ["--background", "--python-exit-code", "1", "--python"] + [
            "{{Task.File.Task}}"
        ]


def test_job_parameters_are_checked(tmp_path):
    with pytest.raises(FarmError, match="empty"):
        params(tmp_path, 5, 4)
    with pytest.raises(FarmError, match="1 to 150"):
        params(tmp_path, size=151)
    with pytest.raises(ValueError, match="ChunkSize"):  # the template's own limit agrees
        job({**params(tmp_path), "ChunkSize": 151})


@pytest.mark.parametrize(
    ("expr", "frames"),
    [("7", [7]), ("1-4", [1, 2, 3, 4]), ("-3--1", [-3, -2, -1]), ("1-7:3", [1, 4, 7])],
)
def test_parse_frames(expr, frames):
    assert farm_job.parse_frames(expr) == frames


@pytest.mark.parametrize("expr", ["", "a", "4-1", "1-3:0", "1..3"])
def test_parse_frames_refuses_what_is_no_range(expr):
    with pytest.raises(FarmError, match="not a frame range"):
        farm_job.parse_frames(expr)


def test_a_cache_needs_consecutive_frames():
    assert farm_job.contiguous([3, 4, 5]) == (3, 5)
    with pytest.raises(FarmError, match="consecutive"):
        farm_job.contiguous([1, 3])


# --- the merge ------------------------------------------------------------------------------------

POINTS = 5


def frame_positions(f, points=POINTS):
    """Positions that tell the frame and the point apart."""
    return np.arange(points * 3, dtype=np.float32).reshape(points, 3) + np.float32(f) / 7


def write_chunk(out, a, b, points=POINTS, name="Bar", start=None, samples=None):
    path = farm_job.chunk_path(str(out), name, a, b)
    os.makedirs(os.path.dirname(path), exist_ok=True)
    n = b - a + 1 if samples is None else samples
    with PC2Writer(path, points, n, a if start is None else start) as w:
        for f in range(a, a + n):
            w.add(frame_positions(f, points))
    return path


def test_merge_writes_the_chunks_in_frame_order(tmp_path):
    for a, b in ((9, 12), (1, 4), (5, 8)):  # written in any order
        write_chunk(tmp_path, a, b)
    write_chunk(tmp_path, 1, 12, name="Other")  # another object's chunk is not read
    path = farm_job.merge(str(tmp_path), "Bar", 1, 12, POINTS)
    assert path == str(tmp_path / "Bar.pc2")
    start, rate, data = read_pc2(path)
    assert (start, rate) == (1.0, 1.0)
    np.testing.assert_array_equal(data, np.stack([frame_positions(f) for f in range(1, 13)]))


def test_merge_refuses_chunks_baked_from_another_version_of_the_file(tmp_path):
    """Each chunk keeps what it was baked from; the merge compares it with the file as it is
    now and names every chunk that differs or keeps no record."""
    paths = [write_chunk(tmp_path, a, b) for a, b in ((1, 4), (5, 8), (9, 12))]
    for p, made in zip(paths, ("v2", "v1", "v2"), strict=True):
        farm_job.write_record(p, made)
    assert farm_job.read_record(paths[0]) == "v2"
    with pytest.raises(FarmError, match=r"chunk\(s\) Bar.0005-0008.pc2 were baked from another"):
        farm_job.merge(str(tmp_path), "Bar", 1, 12, POINTS, baked_from="v2")
    os.unlink(farm_job.record_path(paths[2]))
    with pytest.raises(FarmError, match=r"Bar.0005-0008.pc2, Bar.0009-0012.pc2 were baked"):
        farm_job.merge(str(tmp_path), "Bar", 1, 12, POINTS, baked_from="v2")
    assert not (tmp_path / "Bar.pc2").exists()
    for p in paths:
        farm_job.write_record(p, "v2")
    farm_job.merge(str(tmp_path), "Bar", 1, 12, POINTS, baked_from="v2")
    assert len(read_pc2(str(tmp_path / "Bar.pc2"))[2]) == 12
    assert sorted(os.listdir(tmp_path / "chunks"))[:2] == [
        "Bar.0001-0004.pc2",
        "Bar.0001-0004.pc2.json",
    ]


@pytest.mark.parametrize(
    ("chunks", "match"),
    [
        ([(1, 4), (9, 12)], r"no chunk holds frame\(s\) 5-8 of 'Bar'"),
        ([(1, 4), (5, 8)], r"frame\(s\) 9-12"),
        ([(1, 4), (3, 8), (9, 12)], "Bar.0001-0004.pc2 and Bar.0003-0008.pc2 overlap"),
        ([(1, 4), (5, 8), (9, 13)], "Bar.0009-0013.pc2 reaches beyond frames 1-12"),
        ([(0, 4), (5, 8), (9, 12)], "Bar.0000-0004.pc2 reaches beyond"),
    ],
)
def test_merge_refuses_a_partial_or_ambiguous_cover(tmp_path, chunks, match):
    for a, b in chunks:
        write_chunk(tmp_path, a, b)
    with pytest.raises(FarmError, match=match):
        farm_job.merge(str(tmp_path), "Bar", 1, 12, POINTS)
    assert not (tmp_path / "Bar.pc2").exists()


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"points": POINTS + 1}, "has 6 points, 'Bar' has 5 vertices"),
        ({"samples": 3}, r"holds 3 sample\(s\) from frame 5 \(rate 1\), not frames 5-8"),
        ({"start": 6}, "from frame 6"),
    ],
)
def test_merge_refuses_a_chunk_that_does_not_fit(tmp_path, kw, match):
    write_chunk(tmp_path, 1, 4)
    write_chunk(tmp_path, 5, 8, **kw)
    write_chunk(tmp_path, 9, 12)
    with pytest.raises(FarmError, match=match):
        farm_job.merge(str(tmp_path), "Bar", 1, 12, POINTS)
    assert not (tmp_path / "Bar.pc2").exists()


def test_a_failed_merge_keeps_the_earlier_cache(tmp_path):
    for a, b in ((1, 4), (5, 8), (9, 12)):
        write_chunk(tmp_path, a, b)
    path = farm_job.merge(str(tmp_path), "Bar", 1, 12, POINTS)
    before = pathlib.Path(path).read_bytes()
    with open(farm_job.chunk_path(str(tmp_path), "Bar", 5, 8), "r+b") as f:
        f.truncate(100)  # a chunk cut short (a full disk, a killed copy)
    with pytest.raises(FarmError, match="cannot read chunk"):
        farm_job.merge(str(tmp_path), "Bar", 1, 12, POINTS)
    assert pathlib.Path(path).read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["Bar.pc2", "chunks"]  # no temp file


def test_running_a_chunk_again_replaces_it(tmp_path):
    """A chunk is written to a temporary name and renamed: a re-run replaces it whole, and a
    re-run that fails leaves the old one."""
    path = write_chunk(tmp_path, 5, 8, points=POINTS + 1)
    write_chunk(tmp_path, 5, 8)
    assert read_pc2(path)[2].shape == (4, POINTS, 3)
    with pytest.raises(ValueError), PC2Writer(path, POINTS, 4, 5) as w:
        w.add(frame_positions(5))
        raise ValueError("the task failed half way")
    assert read_pc2(path)[2].shape == (4, POINTS, 3)
    assert os.listdir(os.path.dirname(path)) == [os.path.basename(path)]


class _FullDisk:
    """A file with room for ``room`` writes, whose final flush fails, as on a full disk."""

    def __init__(self, f, room):
        self.f, self.room = f, room

    def write(self, data):
        if self.room == 0:
            raise OSError(errno.ENOSPC, "No space left on device")
        self.room -= 1
        self.f.write(data)

    def close(self):
        self.f.close()
        raise OSError(errno.ENOSPC, "No space left on device")


def test_a_full_disk_or_a_killed_writer_leaves_no_temporary_file(tmp_path, monkeypatch):
    path = str(tmp_path / "Bar.pc2")
    with PC2Writer(path, POINTS, 1, 1) as w:
        w.add(frame_positions(1))
    old = open(path, "rb").read()
    real_open = open
    for room in (0, 1, 2):  # the header, the frame, or the closing flush fails
        disk = lambda *a, room=room: _FullDisk(real_open(*a), room)  # noqa: E731
        monkeypatch.setattr(pointcache, "open", disk, raising=False)
        with pytest.raises(OSError, match="No space"), PC2Writer(path, POINTS, 1, 1) as w:
            w.add(frame_positions(2))
        assert os.listdir(tmp_path) == ["Bar.pc2"] and open(path, "rb").read() == old, room
    monkeypatch.undo()
    # a writer killed half way leaves its temporary file; the next writer removes it, not
    # the temporary file another farm node is writing
    kill = (
        f"import os, signal, sys; sys.path.insert(0, {str(ROOT / 'addon')!r}); "
        "from material_deform.pointcache import PC2Writer; "
        f"w = PC2Writer({path!r}, 3, 2, 1); w.add([[0.0] * 3] * 3); w._f.flush(); "
        "os.kill(os.getpid(), signal.SIGKILL)"
    )
    assert subprocess.run([sys.executable, "-c", kill]).returncode == -signal.SIGKILL
    other = tmp_path / "Bar.pc2.tmp-another-node-1"
    other.write_bytes(b"")
    assert len(os.listdir(tmp_path)) == 3
    with PC2Writer(path, POINTS, 1, 1) as w:
        w.add(frame_positions(2))
    assert sorted(os.listdir(tmp_path)) == ["Bar.pc2", other.name]
    assert read_pc2(path)[2].shape == (1, POINTS, 3)


def test_chunk_names_keep_objects_apart(tmp_path):
    write_chunk(tmp_path, 1, 2, name="Bar.001")
    write_chunk(tmp_path, 1, 2, name="Bar")
    assert os.path.basename(farm_job.chunk_path("o", "Bar.001", 1, 2)) == "Bar.001.0001-0002.pc2"
    assert [c[:2] for c in farm_job.find_chunks(str(tmp_path), "Bar")] == [(1, 2)]
    assert [c[:2] for c in farm_job.find_chunks(str(tmp_path), "Bar.001")] == [(1, 2)]


def test_file_names_differ_for_different_objects():
    """Names that one character map would merge ('Arm.L' / 'Arm L' / 'Arm_L'), names in other
    scripts, and names equal but for case (one file on Windows and macOS) get distinct files."""
    names = [
        "Arm.L",
        "Arm L",
        "Arm_L",
        "Arm:L",
        "arm_l",
        "触手",
        "尻尾",
        "Tä-n.t é/x",
        "CON",
        "Bar.",
    ]
    files = [farm_job.file_name(n, names) for n in names]
    assert len({f.casefold() for f in files}) == len(names), files
    assert files[0] == "Arm.L" and files[5:7] == ["触手", "尻尾"]  # kept as they are
    assert files[2] == "Arm_L-" + hashlib.sha1(b"Arm_L").hexdigest()[:8]  # 'arm_l' is there too
    assert farm_job.file_name("Arm_L") == "Arm_L"  # alone, it keeps its name
    for f in files[1], files[3], files[7], files[8], files[9]:  # changed, reserved, trailing '.'
        assert re.fullmatch(r"[\w.-]+-[0-9a-f]{8}", f) and not f.startswith("CON."), f
    assert all(set(f) <= set("-_.") | {c for c in f if c.isalnum()} for f in files)


# --- the job bundle the submit helpers write ------------------------------------------------------


def test_bundle_is_what_openjd_and_deadline_read(tmp_path):
    p = params(tmp_path)
    folder = tmp_path / "out" / "job"
    cmds = farm_job.write_bundle(str(folder), p)
    assert (folder / "template.yaml").read_text() == TEMPLATE.read_text()
    assert (folder / farm_job.TASK).read_text() == (ROOT / "farm" / farm_job.TASK).read_text()
    deadline = json.loads((folder / "parameter_values.json").read_text())
    assert deadline == {"parameterValues": [{"name": k, "value": v} for k, v in p.items()]}
    assert json.loads((folder / "openjd_params.json").read_text()) == p
    assert cmds["deadline"] == f"deadline bundle submit {folder}"
    readme = (folder / "README.txt").read_text()
    assert all(cmds[k] in readme for k in ("local", "deadline", "chunk", "merge"))
    task = f"{folder / farm_job.TASK}"
    out = p["OutputFolder"]
    blend = p["BlendFile"]
    assert cmds["chunk"] == (
        f"blender -b --python-exit-code 1 --python {task} -- chunk {blend} Bar 1-4 {out}"
    )
    assert cmds["merge"].endswith(f"-- merge {blend} Bar 1-12 {out}")
    # openjd takes the parameter file as written (a summary resolves every parameter)
    summary = subprocess.run(
        [*OPENJD, "summary", str(folder / "template.yaml"), "--output", "json"]
        + ["-p", f"file://{folder / 'openjd_params.json'}"],
        capture_output=True,
        text=True,
    )
    assert summary.returncode == 0, summary.stdout + summary.stderr
    got = json.loads(summary.stdout)
    assert got["name"] == "Material Deform bake: Bar"
    values = {d["name"]: d.get("value") for d in got["parameter_definitions"]}
    assert values == {**{k: str(v) for k, v in p.items()}, "AddonZip": None}  # empty: none


def test_farm_bake_script_writes_the_bundle(tmp_path):
    blend = tmp_path / "scene.blend"
    blend.write_bytes(b"BLENDER")  # only its path matters here
    out = subprocess.run(
        [sys.executable, str(ROOT / "scripts" / "farm_bake.py"), str(blend), "Bar", "1", "24"]
        + [str(tmp_path / "out"), "--chunk-size", "8"],
        capture_output=True,
        text=True,
    )
    assert out.returncode == 0, out.stdout + out.stderr
    folder = tmp_path / "out" / "job"
    p = json.loads((folder / "openjd_params.json").read_text())
    assert p["ChunkSize"] == 8 and p["FrameEnd"] == 24 and p["BlendFile"] == str(blend)
    assert f"openjd run {folder / 'template.yaml'} --step Merge --run-dependencies" in out.stdout
    bad = subprocess.run(
        [sys.executable, str(ROOT / "scripts" / "farm_bake.py"), str(blend), "Bar", "5", "4"]
        + [str(tmp_path / "o2")],
        capture_output=True,
        text=True,
    )
    assert bad.returncode == 2 and "frame range 5-4 is empty" in bad.stderr


def test_docs_give_the_commands_the_bundle_writes():
    """docs/farm.md's example commands are what farm_job writes for its example."""
    out = "/shots/farm_shot_Tentacle"  # the default output folder of shot.blend's Tentacle
    p = farm_job.job_parameters("/shots/shot.blend", "Tentacle", 1, 240, 10, out)
    cmds = farm_job.commands(f"{out}/job", p)
    text = (ROOT / "docs" / "farm.md").read_text()
    for key in ("local", "deadline", "chunk", "merge"):
        assert cmds[key] in text, key
