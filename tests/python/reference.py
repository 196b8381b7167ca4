"""Dense numpy/scipy reference of Popa et al. 2006 Eq. 1-4, written independently of the core:
full (n+m)-unknown system with explicit fourth vertices, scipy's logm/expm for Eq. 2."""

import numpy as np
import scipy.linalg as sla


def dual_pairs(faces):
    edges = {}
    for fi, tri in enumerate(faces):
        for k in range(3):
            a, b = sorted((int(tri[k]), int(tri[(k + 1) % 3])))
            edges.setdefault((a, b), []).append(fi)
    pairs = set()
    for fs in edges.values():
        for i in range(len(fs)):
            for j in range(i + 1, len(fs)):
                pairs.add((min(fs[i], fs[j]), max(fs[i], fs[j])))
    return np.array(sorted(pairs))


def default_bend(faces, shear):
    """(pairs, phi): the dual edges and the paper's default bending phi_fg = (psi_f + psi_g)/2."""
    pairs = dual_pairs(faces)
    return pairs, 0.5 * (shear[pairs[:, 0]] + shear[pairs[:, 1]])


def weights(m, pairs, phi, anchors):
    k = len(anchors)
    L = np.zeros((m, m))
    for (f, g), w in zip(pairs, phi, strict=True):
        L[f, f] += w
        L[g, g] += w
        L[f, g] -= w
        L[g, f] -= w
    fixed = np.concatenate(anchors)
    W = np.zeros((m, k))
    for a, fa in enumerate(anchors):
        W[fa, a] = 1.0
    free = np.setdiff1d(np.arange(m), fixed)
    W[free] = np.linalg.solve(L[np.ix_(free, free)], -L[np.ix_(free, fixed)] @ W[fixed])
    return W


def blend(transforms3, W):
    logs = [sla.logm(T).real for T in transforms3]
    return np.array([sla.expm(sum(w * L for w, L in zip(row, logs, strict=True))) for row in W])


def _polar_logs(T):
    """(log S, axis-angle of R) of T = S R (scipy's left polar decomposition), T (3,3)."""
    R, S = sla.polar(T, side="left")  # T = S @ R
    lam, U = np.linalg.eigh(S)
    K = sla.logm(R).real
    return U @ np.diag(np.log(lam)) @ U.T, np.array([K[2, 1], K[0, 2], K[1, 0]])


def _skew(w):
    return np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])


def blend_polar(transforms3, W):
    """The documented blend for any det > 0 transform (docs/core.md): with T_a = S_a R_a,
    T = expm(sum w log S_a) expm(sum w [log R_a]x). Equals blend() for similarities."""
    logs = [_polar_logs(T) for T in transforms3]
    out = []
    for row in W:
        LS = sum(w * ls for w, (ls, _) in zip(row, logs, strict=True))
        r = sum(w * lr for w, (_, lr) in zip(row, logs, strict=True))
        out.append(sla.expm(LS) @ sla.expm(_skew(r)))
    return np.array(out)


def blend_anisotropic(transforms3, Ws, axes):
    """Sec. 5 blend, one weight field per axis (Ws: three (m,k)): rotation component c of
    anchor a (in the axes' frame) is weighted by Ws[c]; log-stretch by the mean of the three."""
    logs = [_polar_logs(T) for T in transforms3]
    C = np.array([axes.T @ lr for _, lr in logs])  # (k,3)
    out = []
    for i in range(len(Ws[0])):
        w = np.stack([Wc[i] for Wc in Ws], axis=1)  # (k,3)
        r = axes @ (w * C).sum(axis=0)
        LS = sum(wm * ls for wm, (ls, _) in zip(w.mean(axis=1), logs, strict=True))
        out.append(sla.expm(LS) @ sla.expm(_skew(r)))
    return np.array(out)


def follow_positions(V, F, anchors, T):
    """Fixed vertices and their positions in follow mode: each anchor vertex goes to the mean
    of its anchors' full (4,4) transforms."""
    owner = {}
    for a, fa in enumerate(anchors):
        for vi in np.unique(F[fa]):
            owner.setdefault(int(vi), []).append(a)
    fixed = np.array(sorted(owner))
    pos = np.array(
        [np.mean([T[a, :3, :3] @ V[i] + T[a, :3, 3] for a in owner[int(i)]], axis=0) for i in fixed]
    )
    return fixed, pos


def frame(a, b, c):
    n = np.cross(b - a, c - a)
    d = a + n / np.sqrt(np.linalg.norm(n))
    return np.column_stack([b - a, c - a, d - a])


def reposition(V, F, shear, T, fixed, fixed_pos):
    """min sum psi_i |Vt_i V_i^-1 - T_i|_F^2 over n+m unknowns (fourth vertices explicit)."""
    n, m = len(V), len(F)
    N = n + m
    rows = []
    rhs = []
    for i, (a, b, c) in enumerate(F):
        E = np.linalg.inv(frame(V[a], V[b], V[c]))
        D = np.array([[-1, -1, -1], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
        G = D @ E  # (4,3): Vt E = X_loc @ G
        idx = [a, b, c, n + i]
        s = np.sqrt(shear[i])
        for col in range(3):
            row = np.zeros(N)
            for j in range(4):
                row[idx[j]] += s * G[j, col]
            rows.append(row)
            rhs.append(s * T[i][:, col])  # (3,) one value per coordinate
    A = np.array(rows)
    B = np.array(rhs)
    free = np.setdiff1d(np.arange(N), fixed)
    B = B - A[:, fixed] @ fixed_pos
    X = np.zeros((N, 3))
    X[fixed] = fixed_pos
    X[free] = np.linalg.lstsq(A[:, free], B, rcond=None)[0]
    return X[:n]


def polar_blend(transforms3, W, snap=0.0):
    """The method's blend for general matrices (transforms.hpp): M = S R (left polar),
    exp(sum w log S) exp(sum w log R), with scipy's logm/expm and rotation vectors. ``snap``:
    a stretch whose log singular values spread by at most this is replaced by its geometric
    mean times I (the core's kSimilarityTolerance is 1e-6)."""
    from scipy.spatial.transform import Rotation

    logs_s, logs_r = [], []
    for T in transforms3:
        R, S = sla.polar(T, side="left")  # T = S R
        log_sigma = np.log(np.linalg.svd(T, compute_uv=False))
        if np.ptp(log_sigma) <= snap:
            logs_s.append(log_sigma.mean() * np.eye(3))
        else:
            logs_s.append(sla.logm(S).real)
        logs_r.append(Rotation.from_matrix(R).as_rotvec())
    out = []
    for row in W:
        L = sum(w * x for w, x in zip(row, logs_s, strict=True))
        r = sum(w * x for w, x in zip(row, logs_r, strict=True))
        out.append(sla.expm(L) @ Rotation.from_rotvec(r).as_matrix())
    return np.array(out)
