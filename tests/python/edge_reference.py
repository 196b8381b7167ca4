"""Dense numpy/scipy reference of one edge-based iteration (Eq. 4-15), written independently of
the core: edges and face pairs from a dict, alpha/beta by scipy's bounded least squares, the
rest -> current edge frame as explicit 3x3 matrices, and a dense solve of the normal equations.
The carried first step: anchors by scipy's connected components, rotations by an SVD fit, their
spread by a dense solve, quaternions written out by hand.
"""

import numpy as np
from scipy.optimize import lsq_linear
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components


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
    carry=False,
):
    """One E-M iteration from the iterate X (n,3): returns the new iterate (n,3). With carry
    (the solver's first iteration when the anchors turn), the rest parts of the targets are
    turned further by each edge's share of the anchors' rotations (X[constrained] ->
    positions)."""
    n = len(V)
    ts, _ = terms(V, F, stretch, bend, edge_weight, direction)
    turn = carried_rotations(V, F, X, constrained, positions, ts) if carry else None
    A = np.zeros((n, n))
    B = np.zeros((n, 3))

    def add(verts, coef, c, target):
        d = np.zeros(n)
        d[list(verts)] = coef
        A[:] += c * np.outer(d, d)
        B[:] += c * np.outer(d, target)

    for e, t in enumerate(ts):
        a, b = t["edge"]
        q = np.eye(3) if turn is None else turn[e]
        cur = X[a] - X[b]
        rot = q @ (np.linalg.norm(t["rest"]) * cur / np.linalg.norm(cur))
        add((a, b), [1.0, -1.0], t["c_rho"], (1 - p_stretch) * cur + p_stretch * rot)
        s = t["sigma"]
        if s is not None:
            i, j, o, m = s["verts"]
            cur_s = s["coef"] @ X[[i, j, o, m]]
            rot_s = q @ frame(X[i], X[j], X[o], X[m]) @ s["local"]
            add(s["verts"], s["coef"], s["c"], (1 - p_bend) * cur_s + p_bend * rot_s)
    B += 0.5 * np.asarray(gravity, float)[None, :]
    c = np.asarray(constrained)
    free = np.setdiff1d(np.arange(n), c)
    out = np.zeros((n, 3))
    out[c] = positions
    out[free] = np.linalg.solve(A[np.ix_(free, free)], B[free] - A[np.ix_(free, c)] @ positions)
    return out


def quaternion_matrix(q):
    x, y, z, w = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def rotation_vector(R):
    """Axis * angle of a rotation matrix, angle in [0, pi] (not near pi: tests avoid it)."""
    angle = np.arccos(np.clip((np.trace(R) - 1) / 2, -1.0, 1.0))
    if angle < 1e-12:
        return np.zeros(3)
    w = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    return angle * w / (2 * np.sin(angle))


def carried_rotations(V, F, X, constrained, positions, ts):
    """Per term of `ts`, the 3x3 turn of the carried first step."""
    n = len(V)
    c = np.asarray(constrained)
    # anchors: constrained vertices joined by mesh edges
    pairs = np.array([t["edge"] for t in ts])
    inside = np.isin(pairs, c).all(axis=1)
    graph = coo_matrix((np.ones(inside.sum()), tuple(pairs[inside].T)), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    r_c = np.zeros((len(c), 3))
    for lab in np.unique(label[c]):
        k = np.flatnonzero(label[c] == lab)
        if len(k) < 3:
            continue
        x, y = X[c[k]] - X[c[k]].mean(0), positions[k] - positions[k].mean(0)
        u, sv, wt = np.linalg.svd(y.T @ x)
        if sv[1] < 1e-6 * sv[0]:
            continue
        R = u @ np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ wt))]) @ wt
        r_c[k] = rotation_vector(R)
    # spread by the system's own response: A_ff r_f = -A_fc r_c (the measure step's matrix)
    A = np.zeros((n, n))
    for t in ts:
        dr = np.zeros(n)
        dr[list(t["edge"])] = [1.0, -1.0]
        A += t["c_rho"] * np.outer(dr, dr)
        if t["sigma"] is not None:
            ds = np.zeros(n)
            ds[list(t["sigma"]["verts"])] = t["sigma"]["coef"]
            A += t["sigma"]["c"] * np.outer(ds, ds)
    free = np.setdiff1d(np.arange(n), c)
    r = np.zeros((n, 3))
    r[c] = r_c
    r[free] = np.linalg.solve(A[np.ix_(free, free)], -A[np.ix_(free, c)] @ r_c)
    angle = np.linalg.norm(r, axis=1)
    axis = r / np.where(angle > 0, angle, 1.0)[:, None]
    quat = np.column_stack([axis * np.sin(angle / 2)[:, None], np.cos(angle / 2)])
    return [quaternion_matrix(quat[t["edge"][0]] + quat[t["edge"][1]]) for t in ts]
