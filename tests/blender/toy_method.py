"""A toy fifth method, written as a module of ``methods/`` is: the whole mesh moves by the mean
of the anchors' translations since bind, times Strength. test_fifth_method.py loads it as
``material_deform.methods.toy_translate``; nothing else in the add-on knows it."""

from __future__ import annotations

import bpy
from bpy.props import FloatProperty

from .. import updates
from .base import Method, Result, register_method


class ToyTranslateSettings(bpy.types.PropertyGroup):
    strength: FloatProperty(
        name="Strength",
        description="Fraction of the anchors' mean translation the mesh moves by",
        default=1.0,
        update=updates.live_setting,  # live: the pose is solved again, no rebind
    )


class ToyTranslateMethod(Method):
    key = "TOY_TRANSLATE"
    number = 90
    label = "Toy translate"
    description = "Moves the whole mesh by the mean translation of the anchors"
    settings_name = "toy_translate"
    settings_class = ToyTranslateSettings

    def build(self, inputs):
        return inputs.verts_c.copy()  # (n_c,3) rest positions of the compacted mesh

    def check_live(self, obj, entry, depsgraph) -> None:
        # the solve sees only the solver and its state: hand the live setting over
        entry.state["strength"] = float(self.settings_of(obj).strength)

    def solve(self, solver, transforms, state, budget, progress=None, rotations=None) -> Result:
        # rotations: the anchors' turns (None below half a turn); a translation ignores them
        shift = transforms[:, :3, 3].mean(axis=0)  # (3,) in the mesh's local space
        return Result(solver + state.get("strength", 1.0) * shift)


register_method(ToyTranslateMethod())
