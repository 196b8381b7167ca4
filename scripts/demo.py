"""Core demo: deform procedural meshes with a few anchors, uniform vs material-aware, and pose
a tentacle from example shapes.

Writes OBJ files (rest, uniform, material-aware) and a PNG picture into out/ (or --out).
Paper Fig. 1/10: a tentacle whose stiffness grows with its girth curls into a spiral when its
tip is rotated, while uniform material gives a plain arc. Fig. 4: a bar with a stiff middle.
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


def rot(axis, angle):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def tentacle():
    """Tapered tentacle; stiffness proportional to girth (paper Fig. 1/10)."""
    v, f = shapes.tube(length=20.0, radius=lambda t: 1.6 * (1 - 0.9 * t), n_around=24, n_along=160)
    base, tip = shapes.end_faces(v, f, fraction=0.002)
    r = np.linalg.norm(v[:, 1:], axis=1)
    stiff_v = np.maximum(r / r.max(), 1e-3)
    shear = md.shear_from_vertex(f, stiff_v)
    # Log/exp blending takes the short way round, so a single anchor turns by < pi.
    T = np.stack([np.eye(3), rot([0, 0, 1], 0.95 * np.pi)])
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
    T = np.stack([np.eye(3), rot([0, 0, 1], 0.5 * np.pi)])
    pinned = np.unique(f[lo])
    uniform = md.MaterialDeformer(v, f, [lo, hi], pinned=pinned).deform(T)
    material = md.MaterialDeformer(v, f, [lo, hi], shear=shear, pinned=pinned).deform(T)
    return v, f, stiff_v, uniform, material


def bend_in_plane(v, angle, plane_angle, length):
    """Bend a tube along x into an arc of total turn `angle` in the plane through x at
    `plane_angle` about x (0: the xy plane), keeping x = 0 in place."""
    R = rot([1, 0, 0], plane_angle)
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
