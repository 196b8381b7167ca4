"""Run ``blender --command extension ARGS...`` inside the PyPI bpy module, which has no
command-line front end of its own.

    python scripts/blender_command.py extension build --source-dir DIR --output-dir DIR
    python scripts/blender_command.py extension validate FILE.zip

In a Blender binary, ``--command extension`` calls the handler that the bundled ``bl_pkg``
add-on registers with ``bpy.utils.register_cli_command("extension", bl_pkg.cli_extension)``.
The registry itself is not exposed to Python, so this script calls that same handler directly:
the code that builds and validates the extension is Blender's own.
"""

import sys

import bpy


def main(argv: list[str]) -> int:
    if not argv or argv[0] != "extension":
        print("usage: blender_command.py extension SUBCOMMAND [ARGS...]", file=sys.stderr)
        return 2
    import addon_utils  # importable once bpy is (it lives in Blender's scripts/modules)

    if "bl_pkg" not in bpy.context.preferences.addons:
        addon_utils.enable("bl_pkg", default_set=True)
    import bl_pkg

    return int(bl_pkg.cli_extension(argv[1:]) or 0)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
