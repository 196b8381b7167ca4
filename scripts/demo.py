"""Core demo: deform procedural meshes with a few anchors, uniform vs material-aware.

Writes OBJ files (rest, uniform, material-aware) and a PNG picture into out/ (or --out).
Paper Fig. 1/10: a tentacle whose stiffness grows with its girth curls into a spiral when its
tip is rotated, while uniform material gives a plain arc. Fig. 4: a bar with a stiff middle.
Also poses meshes with a few control vertices by pyramid coordinates (demo_pyramid.png): a bar,
and the cat from shared/data/cat-poses when it is there.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Poly3DCollection  # noqa: E402

import matdeform as md  # noqa: E402
from matdeform import shapes  # noqa: E402


def turn_z(angle):
    """(3,3) turn by angle (rad) about z: the library's exp of the axis-angle vector."""
    return md.transform_exp(np.zeros((3, 3)), [0.0, 0.0, angle])


def tentacle():
    """Tapered tentacle; stiffness proportional to girth (paper Fig. 1/10)."""
    v, f = shapes.tube(length=20.0, radius=lambda t: 1.6 * (1 - 0.9 * t), n_around=24, n_along=160)
    base, tip = shapes.end_faces(v, f, fraction=0.002)
    r = np.linalg.norm(v[:, 1:], axis=1)
    stiff_v = np.maximum(r / r.max(), 1e-3)
    shear = md.shear_from_vertex(f, stiff_v)
    # Log/exp blending takes the short way round, so a single anchor turns by < pi.
    T = np.stack([np.eye(3), turn_z(0.95 * np.pi)])
    pinned = np.unique(f[base])
    uniform = md.MaterialDeformer(v, f, [base, tip], pinned=pinned).deform(T)
    material = md.MaterialDeformer(v, f, [base, tip], shear=shear, pinned=pinned).deform(T)
    return v, f, stiff_v, uniform, material


def bar():
    """Bar with a 100x stiffer middle third, bent by rotating one end (Fig. 4)."""
    v, f = shapes.tube(length=12.0, radius=0.8, n_around=16, n_along=90)
    lo, hi = shapes.end_faces(v, f, fraction=0.002)
    xc = v[:, 0]
    stiff_v = np.where((xc > 4.0) & (xc < 8.0), 1.0, 0.01)
    shear = md.shear_from_vertex(f, stiff_v)
    T = np.stack([np.eye(3), turn_z(0.5 * np.pi)])
    pinned = np.unique(f[lo])
    uniform = md.MaterialDeformer(v, f, [lo, hi], pinned=pinned).deform(T)
    material = md.MaterialDeformer(v, f, [lo, hi], shear=shear, pinned=pinned).deform(T)
    return v, f, stiff_v, uniform, material


def draw(ax, v, f, stiff_v, title):
    c = plt.cm.viridis(stiff_v[f].mean(axis=1) / stiff_v.max())
    light = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    light /= np.linalg.norm(light, axis=1, keepdims=True) + 1e-12
    shade = 0.55 + 0.45 * np.abs(
        light @ np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    )
    c[:, :3] *= shade[:, None]
    ax.add_collection3d(Poly3DCollection(v[f], facecolors=c, edgecolors="none"))
    lo, hi = v.min(0), v.max(0)
    mid, half = (lo + hi) / 2, (hi - lo).max() / 2
    ax.set_xlim(mid[0] - half, mid[0] + half)
    ax.set_ylim(mid[1] - half, mid[1] + half)
    ax.set_zlim(mid[2] - half, mid[2] + half)
    ax.view_init(elev=90, azim=-90)
    ax.set_axis_off()
    ax.set_title(title, fontsize=10)


CAT = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "cat-poses"


def pyramid_bar():
    """A bar posed by 8 control vertices: 4 on each end ring, the far end lifted and turned."""
    v, f = shapes.tube(length=10.0, radius=0.7, n_around=16, n_along=60)
    ring0 = np.flatnonzero(np.abs(v[:, 0]) < 1e-9)[:16:4]
    ring1 = np.flatnonzero(np.abs(v[:, 0] - 10.0) < 1e-9)[:16:4]
    ctrl = np.concatenate([ring0, ring1])
    R = turn_z(0.4 * np.pi)
    c = np.array([10.0, 0.0, 0.0])
    target = np.vstack([v[ring0], (v[ring1] - c) @ R.T + [7.0, 4.0, 0.0]])
    X = md.PyramidDeformer(v, f, ctrl).deform(target, tol=1e-7)
    return v, f, ctrl, X


def pyramid_cat():
    """The cat with 9 control vertices (feet, head, tail, back) at their places in pose 3."""
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))
    from bench_pyramid import nine_controls

    v, f = md.read_obj(CAT / "cat-reference.obj")
    pose = md.read_obj(CAT / "cat-03.obj")[0]
    ctrl = nine_controls(v)
    X = md.PyramidDeformer(v, f, ctrl).deform(pose[ctrl], tol=1e-7)
    return v, f, ctrl, X


def draw_posed(ax, v, f, ctrl, title, view):
    draw(ax, v, f, np.ones(len(v)), title)
    ax.scatter(*v[ctrl].T, c="red", s=18, depthshade=False)
    ax.view_init(*view)


def pyramid_figure(out: Path) -> None:
    cases = [("bar", pyramid_bar, (90, -90), [0, 1, 2])]
    if (CAT / "cat-reference.obj").exists():
        cases.append(("cat", pyramid_cat, (12, -65), [2, 0, 1]))  # the cat is y-up
    fig = plt.figure(figsize=(10, 4.5 * len(cases)))
    for row, (name, fn, view, axes) in enumerate(cases):
        v, f, ctrl, X = fn()
        md.write_obj(out / f"{name}_pyramid.obj", X, f)
        for col, (P, label) in enumerate([(v, "rest"), (X, "pyramid coordinates")]):
            ax = fig.add_subplot(len(cases), 2, 2 * row + col + 1, projection="3d")
            title = f"{name}: {label} ({len(ctrl)} control vertices)"
            draw_posed(ax, P[:, axes], f, ctrl, title, view)
    fig.tight_layout()
    fig.savefig(out / "demo_pyramid.png", dpi=100)
    print(f"wrote {out}/demo_pyramid.png")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default="out")
    out = Path(ap.parse_args().out)
    out.mkdir(parents=True, exist_ok=True)
    fig = plt.figure(figsize=(12, 8))
    for row, (name, fn) in enumerate([("tentacle", tentacle), ("bar", bar)]):
        v, f, s, uni, mat = fn()
        md.write_obj(out / f"{name}_rest.obj", v, f)
        md.write_obj(out / f"{name}_uniform.obj", uni, f)
        md.write_obj(out / f"{name}_material.obj", mat, f)
        for col, (X, label) in enumerate(
            [(v, "rest (colour = stiffness)"), (uni, "uniform"), (mat, "material-aware")]
        ):
            draw(
                fig.add_subplot(2, 3, 3 * row + col + 1, projection="3d"),
                X,
                f,
                s,
                f"{name}: {label}",
            )
    fig.tight_layout()
    fig.savefig(out / "demo_core.png", dpi=110)
    print(f"wrote {out}/demo_core.png and OBJ files")
    pyramid_figure(out)


if __name__ == "__main__":
    main()
