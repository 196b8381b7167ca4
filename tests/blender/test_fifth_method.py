"""A fifth method is one module under methods/, registered (docs/methods.md): Bind, the live
update, its settings in the panel and a live setting's update work with no edit of the session,
the operators or the panel. The toy method of toy_method.py is loaded as such a module while
the add-on is unregistered, used, and taken out again."""

import contextlib
import importlib.util
import math
import sys
from pathlib import Path

import addon_utils
import bpy
import numpy as np
import pytest
from helpers import draw_panel, output, rest, tube, two_end_anchors, update
from material_deform import methods, session
from mathutils import Matrix, Vector

ADDON = "material_deform"
TOY = "TOY_TRANSLATE"


@contextlib.contextmanager
def toy_method():
    """The toy registered as methods/toy_translate.py would be at import, then the add-on
    registered again (its Method menu and settings groups come from the registry then); on
    leaving, the add-on unregistered, the toy taken out and the add-on registered again."""
    name = f"{methods.__name__}.toy_translate"
    addon_utils.disable(ADDON, default_set=True)
    spec = importlib.util.spec_from_file_location(name, Path(__file__).with_name("toy_method.py"))
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)  # registers the method
    try:
        assert addon_utils.enable(ADDON, default_set=True) is not None
        yield module
    finally:
        addon_utils.disable(ADDON, default_set=True)
        methods.unregister_method(TOY)
        del sys.modules[name]
        assert addon_utils.enable(ADDON, default_set=True) is not None


def menu_keys(obj):
    return [i.identifier for i in obj.material_deform.bl_rna.properties["method"].enum_items]


def test_a_fifth_method_binds_poses_shows_its_settings_and_leaves_cleanly():
    with toy_method() as toy:
        obj = tube()
        obj.rotation_euler.z = math.pi / 2  # the anchors' motion reaches it in local space
        obj.scale = (2.0, 2.0, 2.0)
        update()
        top, bottom = two_end_anchors(obj)
        s = obj.material_deform
        assert menu_keys(obj)[-1] == TOY
        s.method = TOY
        assert bpy.ops.object.material_deform_bind() == {"FINISHED"}
        r = rest(obj).astype(np.float64)
        np.testing.assert_array_equal(output(obj), rest(obj))  # the bind pose: the rest shape
        d = np.array([[0.4, -0.2, 0.6], [0.0, 1.0, -0.4]])  # world moves of the two Empties
        for anc, move in zip((top, bottom), d, strict=True):
            anc.empty.matrix_world = Matrix.Translation(Vector(move)) @ anc.empty.matrix_world
        update()
        m = np.array(obj.matrix_world)[:3, :3]  # rotation x scale 2
        local = np.linalg.solve(m, d.T).T  # each move in the mesh's local space
        np.testing.assert_allclose(output(obj), r + local.mean(axis=0), atol=1e-5)
        assert session.stale_reason(obj) == ""

        s.toy_translate.strength = 0.5  # a live setting: solved again on the next update
        update()
        np.testing.assert_allclose(output(obj), r + 0.5 * local.mean(axis=0), atol=1e-5)
        assert session.stale_reason(obj) == ""  # no rebind asked

        assert "strength" in draw_panel()  # the default draw shows the method's own setting
        settings_class = toy.ToyTranslateSettings
        assert settings_class.is_registered

    assert not settings_class.is_registered
    obj = tube("After")
    assert TOY not in menu_keys(obj) and not hasattr(obj.material_deform, "toy_translate")
    with pytest.raises(KeyError):
        methods.get(TOY)
    assert [m.key for m in methods.all_methods()] == menu_keys(obj)


def test_a_method_whose_solve_takes_no_rotations_is_refused_when_it_registers():
    """Every solve gets the anchors' rotation vectors (docs/methods.md): a method written
    without the argument fails at once, naming it, instead of on the first twist."""

    class Old(methods.Method):
        key, number = "OLD_SIGNATURE", 91

        def solve(self, solver, transforms, state, budget, progress=None):
            raise AssertionError("never called")

    with pytest.raises(ValueError, match="rotations=None"):
        methods.register_method(Old())
    with pytest.raises(KeyError):
        methods.get("OLD_SIGNATURE")

    class Keywords(Old):
        key, number = "KEYWORDS", 92

        def solve(self, solver, transforms, state, budget, progress=None, **kw):
            raise AssertionError("never called")

    methods.register_method(Keywords())  # **kwargs takes it
    methods.unregister_method("KEYWORDS")
