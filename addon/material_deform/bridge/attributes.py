"""Vertex groups, mesh attributes and colour attributes: the painted stiffness, the stored
stiffness fields and the stiffness display."""

from __future__ import annotations

import contextlib

import numpy as np

from ..errors import BindError
from .arrays import _get

SHEAR_ATTR = "md_shear_stiffness"


BEND_ATTR = "md_bend_stiffness"


BEND_AXES_ATTR = "md_bend_stiffness_xyz"  # anisotropic: one bending stiffness per axis x, y, z


DISPLAY_ATTR = "md_stiffness_display"


def attribute_kind(mesh, name):
    """(domain, data_type) of a mesh attribute, None if there is none of that name."""
    attr = mesh.attributes.get(name)
    return None if attr is None else (attr.domain, attr.data_type)


def vertex_group_weights(obj, names) -> dict[str, np.ndarray]:
    """Weights of the named vertex groups, one pass over the vertices. Missing groups are left
    out of the result; vertices not in a group get -1 so membership (>= 0) stays visible."""
    n = len(obj.data.vertices)
    index = {}
    for name in names:
        vg = obj.vertex_groups.get(name)
        if vg is not None:
            index[vg.index] = name
    out = {name: np.full(n, -1.0) for name in index.values()}
    if not index:
        return out
    for v in obj.data.vertices:
        for g in v.groups:
            name = index.get(g.group)
            if name is not None:
                out[name][v.index] = g.weight
    return out


def has_vertex_group(obj, name) -> bool:
    return obj.vertex_groups.get(name) is not None


def set_vertex_group_weights(obj, name, weights) -> str:
    """Create or overwrite a vertex group with one weight per vertex (all vertices)."""
    vg = obj.vertex_groups.get(name)
    if vg is None:
        vg = obj.vertex_groups.new(name=name)
    w = np.clip(np.asarray(weights, dtype=np.float32), 0.0, 1.0)  # weights are float32
    values, inverse = np.unique(w, return_inverse=True)
    order = np.argsort(inverse, kind="stable")  # one add() per distinct weight
    bounds = np.searchsorted(inverse[order], np.arange(len(values) + 1))
    for k, value in enumerate(values.tolist()):
        vg.add(order[bounds[k] : bounds[k + 1]].tolist(), value, "REPLACE")
    return vg.name


def set_vertex_group(obj, name, vertex_indices):
    vg = obj.vertex_groups.get(name)
    if vg is None:
        vg = obj.vertex_groups.new(name=name)
    vg.add([int(i) for i in vertex_indices], 1.0, "REPLACE")
    return vg.name


def ensure_vertex_group(obj, name) -> bool:
    """Create an empty vertex group ``name`` if there is none; True if created."""
    if obj.vertex_groups.get(name) is not None:
        return False
    obj.vertex_groups.new(name=name)
    return True


def set_active_vertex_group(obj, name) -> None:
    vg = obj.vertex_groups.get(name)
    if vg is not None:
        obj.vertex_groups.active_index = vg.index


def unique_group_name(obj, base) -> str:
    name, i = base, 1
    while obj.vertex_groups.get(name) is not None:
        name = f"{base}.{i:03d}"
        i += 1
    return name


def _write_attribute(mesh, name, domain, data_type, field, values) -> None:
    """(Re)create attribute ``name`` with this domain and type if it differs, then bulk-write."""
    attr = mesh.attributes.get(name)
    if attr is not None and (attr.domain != domain or attr.data_type != data_type):
        mesh.attributes.remove(attr)
        attr = None
    if attr is None:
        attr = mesh.attributes.new(name, data_type, domain)
    attr.data.foreach_set(field, np.asarray(values, dtype=np.float32).ravel())
    mesh.update()


def write_float_attribute(mesh, name, domain, values) -> None:
    """values: (n,) for the n elements of ``domain``."""
    _write_attribute(mesh, name, domain, "FLOAT", "value", values)


def read_float_attribute(mesh, name, domain, n):
    attr = mesh.attributes.get(name)
    if attr is None or attr.domain != domain or attr.data_type != "FLOAT" or len(attr.data) != n:
        return None
    return _get(attr.data, "value", n, np.float32).astype(np.float64)


def write_vector_attribute(mesh, name, domain, values) -> None:
    """values: (n,3) for the n elements of ``domain``."""
    _write_attribute(mesh, name, domain, "FLOAT_VECTOR", "vector", values)


def read_vector_attribute(mesh, name, domain, n):
    attr = mesh.attributes.get(name)
    if (
        attr is None
        or attr.domain != domain
        or attr.data_type != "FLOAT_VECTOR"
        or len(attr.data) != n
    ):
        return None
    return _get(attr.data, "vector", n, np.float32, 3).astype(np.float64)


def remove_attribute(mesh, name) -> bool:
    attr = mesh.attributes.get(name)
    if attr is None:
        return False
    mesh.attributes.remove(attr)
    mesh.update()
    return True


def color_attribute_vertex_rgba(mesh, name):
    """Per-vertex sRGB colour of a colour attribute (corner colours averaged per vertex);
    None if the attribute does not exist."""
    attr = mesh.color_attributes.get(name)
    if attr is None:
        return None
    n = len(attr.data)
    field = "color_srgb" if hasattr(attr.data[0] if n else None, "color_srgb") else "color"
    rgba = _get(attr.data, field, n, np.float32, 4).astype(np.float64)
    if attr.domain == "POINT":
        return rgba
    nv = len(mesh.vertices)
    lv = _get(mesh.loops, "vertex_index", len(mesh.loops), np.int32)
    out = np.zeros((nv, 4))
    for c in range(4):
        out[:, c] = np.bincount(lv, weights=rgba[:, c], minlength=nv)
    cnt = np.bincount(lv, minlength=nv)
    return out / np.maximum(cnt, 1)[:, None]


def color_attribute_writable(obj, name) -> bool:
    """True if ``name`` is a colour attribute or free (vertex groups share the attribute
    namespace in Blender 4+, so a group of that name blocks a new colour attribute)."""
    mesh = obj.data
    if mesh.color_attributes.get(name) is not None:
        return True
    return mesh.attributes.get(name) is None and obj.vertex_groups.get(name) is None


def write_color_attribute_vertex_rgb(mesh, name, rgb) -> None:
    """Write per-vertex sRGB colours (n,3) into a colour attribute, the inverse of
    :func:`color_attribute_vertex_rgba` (a corner attribute gets its vertex's colour on every
    corner; alpha 1). Creates a point FLOAT_COLOR attribute if there is none."""
    attr = mesh.color_attributes.get(name)
    if attr is None:
        attr = mesh.color_attributes.new(name, "FLOAT_COLOR", "POINT")
        if attr is None:
            raise ValueError(f"cannot create color attribute '{name}'")
    rgba = np.ones((len(mesh.vertices), 4), dtype=np.float32)
    rgba[:, :3] = np.clip(rgb, 0.0, 1.0)
    if attr.domain != "POINT":
        rgba = rgba[_get(mesh.loops, "vertex_index", len(mesh.loops), np.int32)]
    n = len(attr.data)
    field = "color_srgb" if n and hasattr(attr.data[0], "color_srgb") else "color"
    attr.data.foreach_set(field, rgba.ravel())
    mesh.update()


def active_color_name(mesh) -> str:
    attr = getattr(mesh.color_attributes, "active_color", None)
    return "" if attr is None else attr.name


def set_active_color(mesh, name) -> bool:
    """Make colour attribute ``name`` the active one (the one Vertex Paint paints and Solid >
    Attribute shading shows). False if there is none of that name."""
    attr = mesh.color_attributes.get(name)
    if attr is None:
        return False
    with contextlib.suppress(AttributeError, TypeError):
        mesh.color_attributes.active_color = attr
    with contextlib.suppress(AttributeError, TypeError):
        mesh.attributes.active_color = attr
    return True


def write_corner_colors(mesh, name, corner_rgba) -> None:
    """Colours (loops,4) as a corner colour attribute (created if missing), made active so
    Attribute viewport shading shows it."""
    attr = mesh.color_attributes.get(name)
    if attr is None:
        attr = mesh.color_attributes.new(name, "BYTE_COLOR", "CORNER")
    rgba = np.asarray(corner_rgba, dtype=np.float32)
    field = "color_srgb" if len(attr.data) and hasattr(attr.data[0], "color_srgb") else "color"
    attr.data.foreach_set(field, rgba.ravel())
    set_active_color(mesh, name)
    mesh.update()


def create_color_attribute(mesh, name, rgba=(0.0, 0.0, 0.0, 1.0)) -> None:
    """A point colour attribute filled with ``rgba``, made active for Vertex Paint."""
    attr = mesh.color_attributes.new(name, "FLOAT_COLOR", "POINT")
    if attr is None:
        raise BindError(f"Cannot create color attribute '{name}'")
    attr.data.foreach_set("color", np.tile(np.asarray(rgba, np.float32), len(attr.data)))
    set_active_color(mesh, name)
    mesh.update()
