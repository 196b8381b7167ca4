"""Dense numpy/scipy reference of one edge-based iteration (Eq. 4-15), written independently of
the core: edges and face pairs from a dict, alpha/beta by scipy's bounded least squares, the
rest -> current edge frame as explicit 3x3 matrices, and a dense solve of the normal equations.
"""

import numpy as np
from scipy.optimize import lsq_linear


def edge_faces(F):
    out = {}
    for fi, tri in enumerate(F):
        for k in range(3):
            a, b = int(tri[k]), int(tri[(k + 1) % 3])
            out.setdefault((min(a, b), max(a, b)), []).append((fi, a, b, int(tri[(k + 2) % 3])))
    return dict(sorted(out.items()))


def frame(xi, xj, xl, xm):
    """Columns l, n, l x n of the edge (i, j) between faces (i, j, l) and (j, i, m)."""
    e = (xi - xj) / np.linalg.norm(xi - xj)
    n = np.cross(xj - xi, xl - xi) + np.cross(xi - xj, xm - xj)
    n = n / np.linalg.norm(n)
    return np.column_stack([e, n, np.cross(e, n)])


def terms(V, F, stretch, bend, edge_weight=None, direction=None):
    """Per edge: dict with the stretch stencil and, for interior manifold edges, the bending one."""
    ef = edge_faces(F)
    E = len(ef)
    w = np.ones(E) if edge_weight is None else np.asarray(edge_weight, float)
    kappa = np.ones(E)
    if direction is not None:
        N = np.zeros_like(V)
        for a, b, c in F:
            cr = np.cross(V[b] - V[a], V[c] - V[a])
            N[[a, b, c]] += cr
        f = np.array(direction, float)
        for v in range(len(V)):
            nn = np.linalg.norm(N[v])
            if nn > 0:
                f[v] -= (f[v] @ N[v]) / nn**2 * N[v]
    out = []
    for e, ((a, b), fl) in enumerate(ef.items()):
        if direction is not None:
            s = f[a] + f[b]
            if np.linalg.norm(s) > 1e-9 * (np.linalg.norm(f[a]) + np.linalg.norm(f[b])):
                r = V[a] - V[b]
                kappa[e] = abs(s @ r) / (np.linalg.norm(s) * np.linalg.norm(r))
        t = {
            "edge": (a, b),
            "c_rho": stretch * w[e] * kappa[e],
            "rest": V[a] - V[b],
            "sigma": None,
        }
        if len(fl) == 2 and fl[0][3] != fl[1][3]:
            _, i, j, o = fl[0]  # o, m: the two opposite vertices (l, m in the paper)
            m = fl[1][3]
            R = frame(V[i], V[j], V[o], V[m])
            n = R[:, 1]
            P = np.eye(3) - np.outer(n, n)
            # sigma = x_j - x_m + alpha (x_i - x_j) - beta (x_l - x_m), tangential part -> 0
            A = np.column_stack([P @ (V[i] - V[j]), -(P @ (V[o] - V[m]))])
            res = lsq_linear(A, -(P @ (V[j] - V[m])), bounds=(0.0, 1.0), tol=1e-14)
            alpha, beta = res.x
            sig = alpha * V[i] + (1 - alpha) * V[j] - beta * V[o] - (1 - beta) * V[m]
            t["sigma"] = {
                "verts": (i, j, o, m),
                "coef": np.array([alpha, 1 - alpha, -beta, beta - 1]),
                "c": bend * w[e] * kappa[e],
                "local": R.T @ sig,  # rest sigma in the rest edge frame
            }
        out.append(t)
    return out, kappa


def iterate(
    V,
    F,
    X,
    constrained,
    positions,
    stretch,
    bend,
    p_stretch=1.0,
    p_bend=1.0,
    gravity=(0, 0, 0),
    edge_weight=None,
    direction=None,
):
    """One E-M iteration from the iterate X (n,3): returns the new iterate (n,3)."""
    n = len(V)
    ts, _ = terms(V, F, stretch, bend, edge_weight, direction)
    A = np.zeros((n, n))
    B = np.zeros((n, 3))

    def add(verts, coef, c, target):
        d = np.zeros(n)
        d[list(verts)] = coef
        A[:] += c * np.outer(d, d)
        B[:] += c * np.outer(d, target)

    for t in ts:
        a, b = t["edge"]
        cur = X[a] - X[b]
        rot = np.linalg.norm(t["rest"]) * cur / np.linalg.norm(cur)
        add((a, b), [1.0, -1.0], t["c_rho"], (1 - p_stretch) * cur + p_stretch * rot)
        s = t["sigma"]
        if s is not None:
            i, j, o, m = s["verts"]
            cur_s = s["coef"] @ X[[i, j, o, m]]
            rot_s = frame(X[i], X[j], X[o], X[m]) @ s["local"]
            add(s["verts"], s["coef"], s["c"], (1 - p_bend) * cur_s + p_bend * rot_s)
    B += 0.5 * np.asarray(gravity, float)[None, :]
    c = np.asarray(constrained)
    free = np.setdiff1d(np.arange(n), c)
    out = np.zeros((n, 3))
    out[c] = positions
    out[free] = np.linalg.solve(A[np.ix_(free, free)], B[free] - A[np.ix_(free, c)] @ positions)
    return out
