"""Core demo: deform procedural meshes with a few anchors, uniform vs material-aware, the
edge-based method's materials (membrane to cloth), and pose a tentacle from example shapes.

Writes OBJ files (rest, uniform, material-aware) and a PNG picture into out/ (or --out).
Paper Fig. 1/10: a tentacle whose stiffness grows with its girth curls into a spiral when its
tip is rotated, while uniform material gives a plain arc. Fig. 4: a bar with a stiff middle.
Also poses meshes with a few control vertices by pyramid coordinates (demo_pyramid.png): a bar,
and the cat (data/cat-poses).
Edge-based (docs/edge.md): a sheet pinned at two corners hanging under gravity, stretch weight
lambda from membrane to cloth (demo_edge_sheet.png), and the paper's Fig. 2a/2c plane
(demo_edge_plane.png).
Pose space (demo_pose_space.png): three example shapes of a tentacle (straight, curled up with a
bulging muscle, bent sideways); its tip handle is dragged between them and beyond them.
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


def bend_in_plane(v, angle, plane_angle, length):
    """Bend a tube along x into an arc of total turn `angle` in the plane through x at
    `plane_angle` about x (0: the xy plane), keeping x = 0 in place."""
    R = md.transform_exp(np.zeros((3, 3)), [plane_angle, 0.0, 0.0])  # turn about x
    q = v @ R  # the bend plane becomes xy
    rho = length / angle
    a = q[:, 0] / rho
    rr = rho - q[:, 1]
    q[:, 0], q[:, 1] = rr * np.sin(a), rho - rr * np.cos(a)
    return q @ R.T


def pose_space():
    """Tentacle examples, and the tip handle dragged between and beyond them."""
    length, n_around = 12.0, 20
    v, f = shapes.tube(length=length, radius=lambda t: 1.0 - 0.6 * t, n_around=n_around, n_along=96)
    x = v[:, 0] / length
    # Example 2 curls up (in the xz plane) with a muscle bulging on its upper, inner side.
    muscle = 0.6 * np.exp(-(((x - 0.35) / 0.1) ** 2)) * np.clip(v[:, 2], 0, None)
    bulged = v.copy()
    bulged[:, 1:] *= 1 + muscle[:, None]
    up, side = 0.5 * np.pi, 0.0
    examples = np.stack(
        [
            v,
            bend_in_plane(bulged, 0.5 * np.pi, up, length),
            bend_in_plane(v, 0.5 * np.pi, side, length),
        ]
    )
    base = np.flatnonzero(x <= 0.02)
    tip = np.flatnonzero(x >= 0.98)
    frame = int(np.flatnonzero(np.isin(f, base).all(1))[0])  # a face of the base handle
    d = md.PoseSpaceDeformer(v, f, examples, [base, tip], frame=frame, coarse=800)
    poses = {
        "between: up and sideways": bend_in_plane(v, 0.5 * np.pi, 0.25 * np.pi, length),
        "between: half way up": bend_in_plane(v, 0.25 * np.pi, up, length),
        "beyond: curled further up": bend_in_plane(v, 0.8 * np.pi, up, length),
    }
    out = []
    for name, target in poses.items():
        X = d.deform([v[base], target[tip]])
        w = ", ".join(f"{x:.2f}" for x in d.example_weights)
        out.append((X, f"{name}\nweights ({w})"))

    def girth(X):
        """Per vertex: distance to its ring's centre over the rest radius (bulges > 1)."""
        ring = np.minimum(np.arange(len(v)) // n_around, 96)
        g = np.ones(len(v))
        for i in range(97):
            idx = np.flatnonzero((ring == i) & (np.arange(len(v)) < 97 * n_around))
            c = X[idx].mean(0)
            g[idx] = np.linalg.norm(X[idx] - c, axis=1) / np.linalg.norm(v[idx, 1:], axis=1)
        return g

    return v, f, examples, out, girth


def draw(ax, v, f, stiff_v, title, view=(90, -90), vmax=None):
    c = plt.cm.viridis(stiff_v[f].mean(axis=1) / (stiff_v.max() if vmax is None else vmax))
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
    ax.view_init(elev=view[0], azim=view[1])
    ax.set_axis_off()
    ax.set_title(title, fontsize=10)


CAT = Path(__file__).resolve().parents[1] / "data" / "cat-poses"


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

    v, f = np.load(CAT / "reference.npy"), np.load(CAT / "faces.npy")
    pose = np.load(CAT / "poses.npy")[2]  # pose 3
    ctrl = nine_controls(v)
    X = md.PyramidDeformer(v, f, ctrl).deform(pose[ctrl], tol=1e-7)
    return v, f, ctrl, X


def draw_posed(ax, v, f, ctrl, title, view):
    draw(ax, v, f, np.ones(len(v)), title)
    ax.scatter(*v[ctrl].T, c="red", s=18, depthshade=False)
    ax.view_init(*view)


def pyramid_figure(out: Path) -> None:
    cases = [("bar", pyramid_bar, (90, -90), [0, 1, 2]), ("cat", pyramid_cat, (12, -65), [2, 0, 1])]
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


def plane(n, size=1.0):
    """(n x n)-square plane in z = 0: (n+1)^2 vertices, 2 n^2 triangles."""
    xs, ys = np.meshgrid(np.linspace(0, size, n + 1), np.linspace(0, size, n + 1))
    v = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], 1)
    a = (np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]).ravel()
    f = np.concatenate([np.stack([a, a + 1, a + n + 2], 1), np.stack([a, a + n + 2, a + n + 1], 1)])
    return v, f


def face_strain(rest, x, f):
    """Mean relative length change of each face's three edges."""
    e = [(0, 1), (1, 2), (2, 0)]
    r = [np.linalg.norm(rest[f[:, a]] - rest[f[:, b]], axis=1) for a, b in e]
    d = [np.linalg.norm(x[f[:, a]] - x[f[:, b]], axis=1) for a, b in e]
    return np.mean([dd / rr - 1.0 for dd, rr in zip(d, r, strict=True)], axis=0)


def draw_strain(ax, x, f, strain, title, lim, view=(12, -62), red=0.5):
    """Faces coloured by edge strain (blue: kept length or shorter, red: `red` or more), lit."""
    c = plt.cm.coolwarm(np.clip(strain / red, 0.0, 1.0))
    n = np.cross(x[f[:, 1]] - x[f[:, 0]], x[f[:, 2]] - x[f[:, 0]])
    n /= np.linalg.norm(n, axis=1, keepdims=True) + 1e-12
    light = np.array([0.4, -0.6, 0.7]) / np.linalg.norm([0.4, -0.6, 0.7])
    c[:, :3] *= (0.45 + 0.55 * np.abs(n @ light))[:, None]
    ax.add_collection3d(Poly3DCollection(x[f], facecolors=c, edgecolors="none"))
    (x0, x1), (y0, y1), (z0, z1) = lim
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_zlim(z0, z1)
    ax.set_box_aspect((x1 - x0, y1 - y0, z1 - z0))
    ax.view_init(*view)
    ax.set_axis_off()
    ax.set_title(title, fontsize=9)


def hanging_sheet():
    """A 40 x 40 sheet pinned at two corners of one side, the pins moved 30 % closer together,
    hanging under the same gravity for lambda from membrane to cloth (bend 1)."""
    v, f = plane(40)
    pins = np.array([0, 40])
    pos = v[pins] + [[0.15, 0.0, 0.0], [-0.15, 0.0, 0.0]]
    results = []
    for lam, name in ((2e-4, "membrane"), (1e-3, ""), (1e-2, ""), (1e-1, "cloth")):
        d = md.EdgeDeformer(v, f, pins, stretch=lam, bend=1.0)
        x = d.solve(pos, iterations=20000, tol=1e-6, gravity=(0.0, 0.0, -1e-6))
        results.append((lam, name, x, d.last_iterations))
    return v, f, results


def edge_demo(out: Path):
    v, f, results = hanging_sheet()
    lim = ((-0.1, 1.1), (-0.1, 1.1), (-2.0, 0.1))
    fig = plt.figure(figsize=(16, 6.5))
    for k, (lam, name, x, its) in enumerate(results):
        md.write_obj(out / f"sheet_lambda_{lam:g}.obj", x, f)
        s = face_strain(v, x, f)
        title = f"lambda = {lam:g} {('(' + name + ')') if name else ''}\n"
        title += f"mean strain {100 * s.mean():+.1f} %, {its} iterations"
        draw_strain(fig.add_subplot(1, 4, k + 1, projection="3d"), x, f, s, title, lim)
    fig.suptitle(
        "Edge-based: sheet pinned at two corners under gravity g = (0, 0, -1e-6), bend 1 "
        "(colour: edge strain, blue <= 0 %, red >= +50 %)",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(out / "demo_edge_sheet.png", dpi=90)

    # Paper Fig. 2a/2c: 101 x 101 plane, corners fixed, centre dragged up by 0.3.
    v, f = plane(100)
    c = np.array([0, 100, 100 * 101, 101 * 101 - 1, 101 * 101 // 2])
    pos = v[c].copy()
    pos[-1, 2] += 0.3
    along_x = np.tile([1.0, 0.0, 0.0], (len(v), 1))
    cases = [
        ("lambda = 0", dict(stretch=0.0)),
        ("lambda = 1e-3", dict(stretch=1e-3)),
        ("lambda = 1e-2", dict(stretch=1e-2)),
        ("lambda = 1", dict(stretch=1.0)),
        ("lambda = 1e-2, field along x", dict(stretch=1e-2, direction=along_x)),
    ]
    fig = plt.figure(figsize=(20, 4.8))
    lim = ((0.0, 1.0), (0.0, 1.0), (-0.05, 0.35))
    for k, (title, kw) in enumerate(cases):
        d = md.EdgeDeformer(v, f, c, bend=1.0, **kw)
        x = d.solve(pos, iterations=3000, tol=1e-6)
        s = face_strain(v, x, f)
        title += f"\nmean strain {100 * s.mean():+.1f} %, {d.last_iterations} iterations"
        ax = fig.add_subplot(1, len(cases), k + 1, projection="3d")
        draw_strain(ax, x, f, s, title, lim, (25, -60), red=0.1)
    fig.suptitle(
        "Edge-based: paper Fig. 2a/2c, 101 x 101 plane with fixed corners, centre dragged up by "
        "0.3 x side, bend 1 (colour: edge strain, blue <= 0 %, red >= +10 %)",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(out / "demo_edge_plane.png", dpi=90)


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
    edge_demo(out)
    pyramid_figure(out)
    print(f"wrote {out}/demo_core.png, demo_edge_*.png, demo_pyramid.png and OBJ files")

    v, f, examples, posed, girth = pose_space()
    fig = plt.figure(figsize=(12, 8))
    labels = ["example 1: rest", "example 2: curled up, muscle bulge", "example 3: bent sideways"]
    shots = [(X, label) for X, label in zip(examples, labels, strict=True)] + posed
    for k, (X, label) in enumerate(shots):
        name = f"pose_space_example{k + 1}" if k < 3 else f"pose_space_pose{k - 2}"
        md.write_obj(out / f"{name}.obj", X, f)
        ax = fig.add_subplot(2, 3, k + 1, projection="3d")
        g = (np.clip(girth(X), 0.9, 1.3) - 0.9) / 0.4
        draw(ax, X, f, 0.15 + 0.85 * g, label, view=(15, -70), vmax=1.0)
    fig.suptitle("pose space: colour = girth over rest girth (bulge brighter)", fontsize=10)
    fig.tight_layout()
    fig.savefig(out / "demo_pose_space.png", dpi=110)
    print(f"wrote {out}/demo_pose_space.png and OBJ files")


if __name__ == "__main__":
    main()
