"""read_obj on files written by hand, not only by write_obj."""

import numpy as np
import pytest

import matdeform as md


def write(tmp_path, text):
    p = tmp_path / "m.obj"
    p.write_text(text, encoding="utf-8")
    return p


def test_tabs_texture_normal_indices_and_quads(tmp_path):
    p = write(
        tmp_path,
        "# a quad and a triangle\no thing\nv\t0 0 0\nv 1 0 0  \nv\t1\t1\t0\nv 0 1 0\n"
        "vt 0 0\nvn 0 0 1\ns off\nusemtl red\n"
        "f 1/1/1 2/1/1 3/1/1 4/1/1\nf\t1//1\t3//1\t4//1\n",
    )
    v, f = md.read_obj(p)
    np.testing.assert_array_equal(v, [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    np.testing.assert_array_equal(f, [[0, 1, 2], [0, 2, 3], [0, 2, 3]])  # quad fan + triangle
    assert f.dtype == np.int64 and v.dtype == np.float64


def test_negative_indices_are_relative_to_the_vertices_so_far(tmp_path):
    p = write(tmp_path, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\nv 0 0 1\nf -4 -3 -1\n")
    v, f = md.read_obj(p)
    assert len(v) == 4
    np.testing.assert_array_equal(f, [[0, 1, 2], [0, 1, 3]])


def test_trailing_comment_on_a_record(tmp_path):
    v, f = md.read_obj(write(tmp_path, "v 0 0 0 # origin\nv 1 0 0\nv 0 1 0\nf 1 2 3 # tri\n"))
    assert v.shape == (3, 3) and f.tolist() == [[0, 1, 2]]


@pytest.mark.parametrize(
    "text, match",
    [
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", r"m.obj:4: face index 4 out of range"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", r"face index 0 out of range"),
        ("v 0 0 0\nv 1 0 0\nf -3 -2 -1\n", r"face index -3 out of range"),
        ("v 0 0\n", r"m.obj:1: a vertex needs 3 coordinates"),
        ("v 0 zero 0\n", r"malformed vertex"),
        ("v 0 0 0\nv 1 0 0\nf 1 2\n", r"at least 3 corners"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 x 3\n", r"malformed face index 'x'"),
    ],
)
def test_malformed_files_name_the_line(tmp_path, text, match):
    with pytest.raises(ValueError, match=match):
        md.read_obj(write(tmp_path, text))


def test_round_trip_with_write_obj(tmp_path):
    v, f = md.shapes.tube(n_around=5, n_along=3)
    md.write_obj(tmp_path / "t.obj", v, f)
    v2, f2 = md.read_obj(tmp_path / "t.obj")
    np.testing.assert_allclose(v2, v, rtol=1e-8)
    np.testing.assert_array_equal(f2, f)
