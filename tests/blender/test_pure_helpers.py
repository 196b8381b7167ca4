"""bpy-free helpers of the add-on (stiffness mapping, anchor maths, platform check)."""

import sys
from pathlib import Path

import numpy as np
import pytest
from material_deform import anchor_math as am
from material_deform import platform_check as pc
from material_deform import stiffness_map as sm


def test_paint_to_stiffness_log_scale():
    s = sm.paint_to_stiffness([0.0, 0.5, 1.0, -1.0, 2.0], span=3.0)
    np.testing.assert_allclose(s, [1e-3, 10**-1.5, 1.0, 1e-3, 1.0], rtol=1e-12)
    assert sm.stiffness_range(4.0) == (1e-4, 1.0)
    np.testing.assert_allclose(sm.stiffness_to_paint(s[:3], 3.0), [0, 0.5, 1], atol=1e-12)


def test_dual_edge_bend_inside_polygon_and_across_edges():
    # quad 0 (tris 0,1) next to triangle polygon 1 (tri 2), sharing edge (1,2)
    tris = np.array([[0, 1, 2], [0, 2, 3], [1, 4, 2]])
    tri_poly = np.array([0, 0, 1])
    psi = np.array([2.0, 8.0])
    edges = np.array([[0, 1], [1, 2], [2, 3], [3, 0], [1, 4], [4, 2]])
    phi = np.array([1, 7.0, 1, 1, 1, 1])
    dual = np.array([[0, 1], [0, 2]])
    np.testing.assert_allclose(sm.dual_edge_bend(tris, dual, tri_poly, psi, edges, phi), [2, 7])


def test_edge_stiffness_is_mean_of_adjacent_faces():
    # two quads sharing edge 1
    loop_vert = np.array([0, 1, 4, 3, 1, 2, 5, 4])
    loop_edge = np.array([0, 1, 2, 3, 4, 5, 6, 1])
    loop_poly = sm.loop_polygon_index([0, 4], [4, 4])
    phi = sm.edge_stiffness(np.array([1.0, 3.0]), loop_edge, loop_poly, 7)
    assert phi[1] == 2.0 and phi[0] == 1.0 and phi[4] == 3.0
    p = sm.face_paint_from_vertex(np.arange(6.0), loop_vert, loop_poly, 2)
    np.testing.assert_allclose(p, [2.0, 3.0])


def test_anchor_transform_is_relative_motion_in_object_space():
    rng = np.random.default_rng(1)
    m_obj = np.eye(4)
    m_obj[:3, :3] = 2 * np.linalg.qr(rng.normal(size=(3, 3)))[0]
    m_obj[:3, 3] = [1, 2, 3]
    bind = np.eye(4)
    bind[:3, 3] = [0.5, 0, 0]
    move = np.eye(4)
    move[:3, 3] = [0, 0, 1]
    t = am.anchor_transform(m_obj, move @ bind, bind)
    p_local = np.array([0.3, -0.2, 0.7, 1])
    # moving the Empty by `move` in world moves a point of the mesh by `move` in world
    np.testing.assert_allclose(m_obj @ t @ p_local, move @ m_obj @ p_local, atol=1e-12)


def test_compaction():
    used, t = am.compact(np.array([[0, 2, 3]]), 5)
    assert used.tolist() == [0, 2, 3] and t.tolist() == [[0, 1, 2]]


def test_pose_transforms_cache_follows_object_and_bind_matrices():
    rng = np.random.default_rng(3)
    m = np.zeros((6, 4, 4))
    m[:, :3, :] = rng.normal(size=(6, 3, 4))
    m[:, 3, 3] = 1
    pose = am.PoseTransforms()
    for m_obj in (m[0], m[0], m[5]):  # repeat (cached inverses), then the object moved
        np.testing.assert_allclose(
            pose(m_obj, m[1:3], m[3:5]), am.anchor_transforms(m_obj, m[1:3], m[3:5]), atol=1e-12
        )
    np.testing.assert_allclose(  # a rebind (new bind matrices) is picked up too
        pose(m[5], m[1:3], m[2:4]), am.anchor_transforms(m[5], m[1:3], m[2:4]), atol=1e-12
    )


def test_affine_inverse_inverts_and_rejects_zero_scale():
    rng = np.random.default_rng(2)
    m = np.zeros((5, 4, 4))
    m[:, :3, :] = rng.normal(size=(5, 3, 4))
    m[:, 3, 3] = 1
    np.testing.assert_allclose(
        am.affine_inverse(m) @ m, np.broadcast_to(np.eye(4), m.shape), atol=1e-9
    )
    flat = m[:2].copy()
    flat[1, :3, 2] = 0.0  # an Empty scaled to zero along one axis
    with pytest.raises(ValueError, match="singular"):
        am.affine_inverse(flat)
    np.testing.assert_allclose(
        am.anchor_transforms(m[0], m[1:3], m[3:5])[1],
        np.linalg.inv(m[0]) @ m[2] @ np.linalg.inv(m[4]) @ m[0],
        atol=1e-9,
    )


LINUX = {"python": (3, 11), "implementation": "cpython", "os": "linux", "machine": "x86_64"}
LINUX["glibc"] = (2, 36)


def test_platform_check_reads_the_tags_of_either_zip(tmp_path):
    assert pc.wheel_tags(str(tmp_path)) == []  # a source tree: nothing to check
    ext = tmp_path / "ext" / "wheels"
    ext.mkdir(parents=True)
    (ext / "matdeform-0.1.0-cp311-cp311-manylinux_2_17_x86_64.manylinux2014_x86_64.whl").touch()
    assert pc.wheel_tags(str(ext.parent)) == [
        "cp311-cp311-manylinux_2_17_x86_64",
        "cp311-cp311-manylinux2014_x86_64",
    ]
    info = tmp_path / "legacy" / "_vendor" / "matdeform-0.1.0.dist-info"
    info.mkdir(parents=True)
    (info / "WHEEL").write_text("Wheel-Version: 1.0\nTag: cp313-cp313-linux_x86_64\n")
    assert pc.wheel_tags(str(tmp_path / "legacy")) == ["cp313-cp313-linux_x86_64"]


def test_platform_check_reads_every_bundled_core(tmp_path):
    """A zip carries one core per Python that Blender ships: every wheel's tags count."""
    ext = tmp_path / "ext" / "wheels"
    ext.mkdir(parents=True)
    for cp in ("cp311", "cp313"):
        (ext / f"matdeform-0.1.0-{cp}-{cp}-manylinux_2_35_x86_64.whl").touch()
    tags = pc.wheel_tags(str(ext.parent))
    assert tags == ["cp311-cp311-manylinux_2_35_x86_64", "cp313-cp313-manylinux_2_35_x86_64"]
    info = tmp_path / "legacy" / "_vendor" / "matdeform-0.1.0.dist-info"
    info.mkdir(parents=True)
    (info / "WHEEL").write_text("Tag: " + "\nTag: ".join(tags) + "\n")
    assert pc.wheel_tags(str(tmp_path / "legacy")) == tags
    for py in ((3, 11), (3, 13)):
        assert pc.problem(tags, {**LINUX, "python": py}) is None, py
    why = pc.problem(tags, {**LINUX, "python": (3, 10)})
    both = "CPython 3.11 on Linux x86-64 (glibc 2.35 or newer) and CPython 3.13 on Linux"
    assert f"built for {both}" in why, why
    assert "this Blender has Python 3.10" in why


def test_platform_check_accepts_only_what_the_core_was_built_for():
    ok = ["cp311-cp311-manylinux_2_35_x86_64"]
    assert pc.problem(ok, LINUX) is None
    assert pc.problem([], LINUX) is None
    assert pc.problem(["cp311-cp311-linux_x86_64"], LINUX) is None  # MD_SYSTEM_LIBS build
    assert pc.problem(["cp311-cp311-manylinux2014_x86_64"], {**LINUX, "glibc": (2, 17)}) is None
    old = pc.problem(ok, {**LINUX, "glibc": (2, 31)})
    assert "Linux x86-64 (glibc 2.35 or newer)" in old and "glibc 2.31" in old, old
    py = pc.problem(ok, {**LINUX, "python": (3, 13)})
    assert "built for CPython 3.11" in py and "Python 3.13" in py, py
    assert pc.problem(ok, {**LINUX, "machine": "aarch64"}) is not None
    assert pc.problem(ok, {**LINUX, "glibc": None}) is not None  # musl
    win = {**LINUX, "os": "win32", "machine": "amd64", "glibc": None}
    assert "this Blender has Python 3.11 on Windows x86-64" in pc.problem(ok, win)
    assert pc.problem(["cp311-cp311-win_amd64"], win) is None
    mac = {**LINUX, "os": "darwin", "machine": "arm64", "glibc": None}
    assert pc.problem(["cp311-cp311-macosx_11_0_universal2"], mac) is None
    assert pc.problem(["cp311-cp311-macosx_11_0_x86_64"], mac) is not None
    assert pc.problem(["cp38-abi3-manylinux_2_35_x86_64"], LINUX) is None
    assert pc.problem(["cp312-abi3-manylinux_2_35_x86_64"], LINUX) is not None


def test_platform_check_here_passes_for_the_built_zips():
    """The zips built on this machine (scripts/build_addon.sh) carry a core that runs here."""
    here = pc.current()
    assert here["python"] == sys.version_info[:2] and here["os"] == sys.platform
    legacy = Path(__file__).resolve().parents[2] / "build" / "addon" / "legacy" / "material_deform"
    tags = pc.wheel_tags(str(legacy))
    if not tags:
        pytest.skip(f"{legacy} not built (run scripts/build_addon.sh)")
    assert pc.problem(tags, here) is None, pc.problem(tags, here)


def _area(p, t):
    return 0.5 * np.linalg.norm(np.cross(p[t[:, 1]] - p[t[:, 0]], p[t[:, 2]] - p[t[:, 0]]), axis=1)


def test_polygons_with_collinear_corners_get_triangles_without_flat_ones():
    """A cap n-gon with corners in the middle of its edges, tilted in space: k-2 triangles in
    the polygon's winding, none flat, covering exactly its area."""
    from material_deform import triangulation as tr

    angle = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    ring = np.stack([np.cos(angle), np.sin(angle), np.zeros(12)], axis=1)
    mids = (ring + np.roll(ring, -1, axis=0)) / 2
    cap = np.insert(ring, [1, 5, 6], mids[[0, 4, 5]], axis=0)  # 3 corners on straight edges
    turn = np.linalg.qr(np.arange(9.0).reshape(3, 3) + np.eye(3) * 5)[0]
    p = cap @ turn.T + [3.0, -1.0, 2.0]
    t = tr.polygon_triangles(p, 1e-12)
    assert t.shape == (len(p) - 2, 3) and sorted(set(t.ravel())) == list(range(len(p)))
    assert _area(p, t).min() > 1e-3
    np.testing.assert_allclose(_area(p, t).sum(), 6 * np.sin(2 * np.pi / 12), rtol=1e-12)
    normal = turn @ [0.0, 0.0, 1.0]
    assert (np.cross(p[t[:, 1]] - p[t[:, 0]], p[t[:, 2]] - p[t[:, 0]]) @ normal > 0).all()
    # a square with a corner in the middle of one side; a polygon with no area at all
    sq = np.array([[0, 0, 0], [1, 0, 0], [1, 0.5, 0], [1, 1, 0], [0, 1, 0]], float)
    areas = _area(sq, tr.polygon_triangles(sq, 1e-12))
    assert len(areas) == 3 and areas.min() > 0.2 and abs(areas.sum() - 1.0) < 1e-12
    assert tr.polygon_triangles(np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0.0]]), 1e-12) is None
    # in a mesh: only the polygon holding a flat triangle is triangulated again
    rest = np.vstack([sq, [[2, 0, 0], [2, 1, 0]]])
    tris = np.array([[1, 2, 3], [0, 1, 3], [0, 3, 4], [1, 5, 6], [1, 6, 3]])
    tri_poly = np.array([0, 0, 0, 1, 1])
    loops = np.array([0, 1, 2, 3, 4, 1, 5, 6, 3])
    out = tr.without_flat_triangles(
        rest, tris, tri_poly, np.array([0, 5]), np.array([5, 4]), loops, 1e-12
    )
    np.testing.assert_array_equal(out[3:], tris[3:])
    assert _area(rest, out[:3]).min() > 0.1 and set(out[:3].ravel()) == {0, 1, 2, 3, 4}


def test_face_regions_counts_the_separate_parts():
    strip = np.array([[i, i + 1, i + 2] for i in range(40)])  # 40 triangles, one chain
    assert am.face_regions(strip) == 1
    assert am.face_regions(strip[::-1]) == 1  # order does not matter
    two = np.vstack([strip, strip + 100])
    assert am.face_regions(two) == 2
    perm = np.random.default_rng(3).permutation(200)
    assert am.face_regions(perm[two]) == 2  # nor vertex numbers
    fan = np.array([[0, 1, 2], [0, 3, 4], [5, 6, 7]])  # joined at one vertex, and one apart
    assert am.face_regions(fan) == 2 and am.face_regions(fan[:0]) == 0
