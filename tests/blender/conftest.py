"""Runs both inside Blender (``blender -b --factory-startup --python tests/blender/run.py``) and
with the PyPI ``bpy`` module (``python -m pytest tests/blender``)."""

import os
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
for extra in reversed(os.environ.get("MD_TEST_SYS_PATH", "").split(os.pathsep)):
    if extra and extra not in sys.path:
        sys.path.insert(0, extra)
if str(REPO / "addon") not in sys.path:
    sys.path.insert(0, str(REPO / "addon"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import bpy  # noqa: E402
import pytest  # noqa: E402


@pytest.fixture(scope="session", autouse=True)
def _addon_enabled():
    import addon_utils  # only importable once bpy has set up Blender's module path

    mod = addon_utils.enable("material_deform", default_set=True)
    assert mod is not None, "material_deform add-on failed to enable"
    yield mod


@pytest.fixture(autouse=True)
def fresh_scene():
    """Factory-startup empty scene per test; the add-on stays enabled."""
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    yield bpy.context.scene


# The bpy module (4.x, 5.x) can hang for good in its exit handlers: its delayed file-close
# thread and the destructor of the state it waits on deadlock (seen after all tests passed:
# main thread in pthread_cond_destroy, the thread in delayed_close_thread_run). So under the
# module, leave with pytest's status as soon as everything is reported. Inside the Blender
# executable (tests/blender/run.py) Blender exits normally.
_exit_status = [0]


def pytest_sessionfinish(session, exitstatus):
    _exit_status[0] = int(exitstatus)


@pytest.hookimpl(trylast=True)
def pytest_unconfigure(config):
    if os.environ.get("MD_TESTS_IN_BLENDER") != "1":
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(_exit_status[0])
