"""Write the farm bake job of one object of a saved .blend, without opening Blender (what the
add-on's *Write Farm Bake Job* writes), and optionally run it here with openjd (docs/farm.md).

    python scripts/farm_bake.py scene.blend Tentacle 1 240 /farm/out [--chunk-size 10]
        [--blender /opt/blender/blender] [--addon-zip dist/material_deform-0.1.0-legacy.zip]
        [--run]

Writes the job bundle into <out>/job/ and prints the commands that run it: ``openjd run``
here, ``deadline bundle submit`` for AWS Deadline Cloud. ``--run`` runs the first one (needs
openjd-cli, ``pip install openjd-cli``) and exits with its status. No network, no credentials.
"""

from __future__ import annotations

import argparse
import os
import shlex
import shutil
import subprocess
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), os.pardir, "addon"))

from material_deform import farm_job  # noqa: E402  (no bpy: importable anywhere)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("blend", help="the saved .blend with the bound object")
    ap.add_argument("object", help="the bound mesh object to bake")
    ap.add_argument("frame_start", type=int)
    ap.add_argument("frame_end", type=int)
    ap.add_argument("output", help="output folder (job bundle, chunks, merged .pc2, .blend)")
    ap.add_argument("--chunk-size", type=int, default=10, help="frames per task (1-150)")
    ap.add_argument("--blender", default="blender", help="Blender executable on the workers")
    ap.add_argument("--addon-zip", default="", help="legacy add-on zip to ship with the job")
    ap.add_argument("--run", action="store_true", help="run the job here with openjd")
    a = ap.parse_args(argv)
    if not os.path.isfile(a.blend):
        ap.error(f"no .blend at {a.blend}")
    try:
        params = farm_job.job_parameters(
            a.blend,
            a.object,
            a.frame_start,
            a.frame_end,
            a.chunk_size,
            a.output,
            a.blender,
            a.addon_zip,
        )
        folder = os.path.join(params["OutputFolder"], "job")
        cmds = farm_job.write_bundle(folder, params)
    except (farm_job.FarmError, OSError) as exc:
        print(f"{farm_job.PREFIX} ERROR: {exc}", file=sys.stderr)
        return 2
    print(f"job bundle: {folder}")
    print(f"run here:   {cmds['local']}")
    print(f"submit:     {cmds['deadline']}")
    if a.run:  # openjd on PATH, else next to this Python (a venv that is not activated)
        cmd = shlex.split(cmds["local"])
        cmd[0] = shutil.which("openjd") or os.path.join(os.path.dirname(sys.executable), "openjd")
        return subprocess.call(cmd)
    return 0


if __name__ == "__main__":
    sys.exit(main())
