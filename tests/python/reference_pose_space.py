"""Dense numpy/scipy reference of the single-resolution pose-space pipeline (docs/pose_space.md),
written independently of the core: explicit 9-unknowns-per-face least squares for step 1, scipy's
least_squares for the geodesic natural shape, explicit fourth vertices for step 2, scipy's
polar and Rotation for the algebra. Small meshes only."""

import numpy as np
import scipy.linalg as sla
from reference import dual_pairs, frame
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation


def logm_rot(R):
    return Rotation.from_matrix(R).as_rotvec()


def expm_rot(w):
    return Rotation.from_rotvec(w).as_matrix()


def kabsch(P, Q):
    """R minimising sum |R (p - mean p) - (q - mean q)|^2 (non-degenerate sets)."""
    H = (P - P.mean(0)).T @ (Q - Q.mean(0))
    u, _, vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(vt.T @ u.T))
    return vt.T @ np.diag([1.0, 1.0, d]) @ u.T


def planarity(P):
    if len(P) < 3:
        return 0.0
    ev = np.linalg.eigvalsh((P - P.mean(0)).T @ (P - P.mean(0)))
    return np.sqrt(max(ev[1], 0) / ev[2]) if ev[2] > 0 else 0.0


def gradients(V, X, F):
    return np.array([frame(*X[f]) @ np.linalg.inv(frame(*V[f])) for f in F])


def rbf_weights(P, x):
    """Cardinal phi(r) = r interpolation with a constant term."""
    p = len(P)
    if p == 1:
        return np.ones(1)
    Phi = np.linalg.norm(P[:, None] - P[None], axis=2)
    S = np.zeros((p + 1, p + 1))
    S[:p, :p] = Phi
    S[:p, p] = 1
    S[p, :p] = 1
    rhs = np.zeros((p + 1, p))
    rhs[:p] = np.eye(p)
    sol = np.linalg.solve(S, rhs)
    A, b = sol[:p], sol[p]
    return A.T @ np.linalg.norm(P - x, axis=1) + b


class Reference:
    def __init__(
        self,
        V,
        F,
        examples,
        handles,
        rotational=(),
        position_weight=100.0,
        rotation_weight=1.0,
        joint_weight=100.0,
        orientation_weight=1.0,
        reliability_angle=0.5,
        area_weights=False,
    ):
        self.V, self.F = np.asarray(V, float), np.asarray(F)
        self.ex = [np.asarray(e, float) for e in examples]
        self.H = [np.asarray(h) for h in handles]
        self.Hall = np.concatenate(self.H)
        self.rot = [tuple(r) for r in rotational]
        self.lp, self.lh, self.lj = position_weight, rotation_weight, joint_weight
        self.ow = orientation_weight
        self.diag = np.linalg.norm(self.V.max(0) - self.V.min(0))
        self.pairs = dual_pairs(self.F)
        m = len(self.F)
        # encodings: T = R S (right polar), relative logs per dual edge
        self.S, self.omega, self.Rex = [], [], []
        for X in self.ex:
            T = gradients(self.V, X, self.F)
            R = np.empty_like(T)
            S = np.empty_like(T)
            for i in range(m):
                R[i], S[i] = sla.polar(T[i], side="right")
            self.Rex.append(R)
            self.S.append(S)
            self.omega.append(
                np.array([logm_rot(R[a].T @ R[b]) for a, b in self.pairs]).reshape(-1, 3)
            )
        cost = (
            np.max([np.linalg.norm(o, axis=1) for o in self.omega], axis=0)
            if self.ex
            else np.zeros(len(self.pairs))
        )
        self.wedge = 1.0 / (1.0 + (cost / reliability_angle) ** 2)
        self.oriented = [
            j for j, h in enumerate(self.H) if len(h) >= 3 and planarity(self.V[h]) > 1e-3
        ]
        self.handle_faces = []  # (face, handle)
        owner = -np.ones(len(self.V), int)
        for j, h in enumerate(self.H):
            owner[h] = j
        for i, f in enumerate(self.F):
            if owner[f[0]] >= 0 and (owner[f] == owner[f[0]]).all():
                self.handle_faces.append((i, owner[f[0]]))
        c = self.V[self.F].mean(1)
        d = ((c - self.V.mean(0)) ** 2).sum(1)
        self.root = int(np.lexsort((c[:, 2], c[:, 1], c[:, 0], d))[0])
        # step-2 penalty scale: mean diagonal of the fourth-vertex-eliminated matrix
        diag = np.zeros(len(self.V))
        D = np.array([[-1, -1, -1], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
        a, b, c = (self.V[self.F[:, k]] for k in range(3))
        area = np.linalg.norm(np.cross(b - a, c - a), axis=1)
        self.area = area / area.mean() if area_weights else np.ones(len(self.F))
        self.Gs = []
        for i, f in enumerate(self.F):
            G = D @ np.linalg.inv(frame(*self.V[f]))
            self.Gs.append(G)
            Hm = self.area[i] * G @ G.T
            for lc in range(3):
                diag[f[lc]] += Hm[lc, lc] - Hm[lc, 3] ** 2 / Hm[3, 3]
        self.lam_p = position_weight * diag.mean()

    # --- pose
    def pose(self, X_h, joints):
        """X_h: concatenated handle positions."""
        R = kabsch(self.V[self.Hall], X_h)
        o = X_h.mean(0)
        off = np.cumsum([0] + [len(h) for h in self.H])
        x = [R.T @ (X_h[off[j] : off[j + 1]].mean(0) - o) / self.diag for j in range(len(self.H))]
        for j in self.oriented:
            Rj = kabsch(self.V[self.H[j]], X_h[off[j] : off[j + 1]])
            x.append(self.ow * logm_rot(R.T @ Rj) / np.pi)
        if joints is not None:
            x += [logm_rot(G) / np.pi for G in joints]
        return np.concatenate(x)

    def weights(self, hp, joints=None):
        if not self.ex:
            return np.zeros(0)
        P = []
        for k, X in enumerate(self.ex):
            J = None
            if joints is not None:
                J = [self.Rex[k][a].T @ self.Rex[k][b] for a, b in self.rot]
            P.append(self.pose(X[self.Hall], J))
        return rbf_weights(np.array(P), self.pose(np.concatenate(hp), joints))

    # --- step 1
    def links(self, Q, joints):
        L = [(a, b, self.wedge[e], Q[e]) for e, (a, b) in enumerate(self.pairs)]
        if joints is not None:
            L += [(a, b, self.lj, G) for (a, b), G in zip(self.rot, joints, strict=True)]
        return L

    def chordal(self, links, targets, fixed):
        """min sum w |R_b - R_a Q|^2 + sum lam |R_f - Z_f|^2, R = I on fixed; then polar."""
        m = len(self.F)
        free = [i for i in range(m) if i not in fixed]
        col = {f: k for k, f in enumerate(free)}
        rows, rhs = [], []
        for a, b, w, Q in links:
            s = np.sqrt(w)
            for r in range(3):
                for c in range(3):
                    row = np.zeros(9 * len(free))
                    val = 0.0
                    if b in col:
                        row[9 * col[b] + 3 * r + c] += s
                    else:
                        val -= s * (1.0 if r == c else 0.0)
                    for k in range(3):
                        if a in col:
                            row[9 * col[a] + 3 * r + k] -= s * Q[k, c]
                        else:
                            val += s * (1.0 if r == k else 0.0) * Q[k, c]
                    rows.append(row)
                    rhs.append(val)
        for f, Z in targets:
            s = np.sqrt(self.lh)
            for r in range(3):
                for c in range(3):
                    row = np.zeros(9 * len(free))
                    row[9 * col[f] + 3 * r + c] = s
                    rows.append(row)
                    rhs.append(s * Z[r, c])
        x = np.linalg.lstsq(np.array(rows), np.array(rhs), rcond=None)[0]
        R = np.tile(np.eye(3), (m, 1, 1))
        for f, k in col.items():
            u, _, vt = np.linalg.svd(x[9 * k : 9 * k + 9].reshape(3, 3))
            if np.linalg.det(u @ vt) < 0:
                u[:, 2] *= -1
            R[f] = u @ vt
        return R

    def geodesic(self, links, start, fixed):
        m = len(self.F)
        free = [i for i in range(m) if i not in fixed]

        def rots(xi):
            R = start.copy()
            for k, f in enumerate(free):
                R[f] = expm_rot(xi[3 * k : 3 * k + 3]) @ start[f]
            return R

        def res(xi):
            R = rots(xi)
            return np.concatenate(
                [np.sqrt(w) * logm_rot(R[a] @ Q @ R[b].T) for a, b, w, Q in links]
            )

        sol = least_squares(res, np.zeros(3 * len(free)), xtol=1e-15, ftol=1e-15, gtol=1e-15)
        return rots(sol.x)

    # --- step 2
    def positions(self, T, rows):
        """min sum a_i |X_i E_i - T_i|^2 + lam sum |x_v - t_v|^2, explicit fourth vertices. rows:
        list of (v, t); without rows the translation is fixed by the rest vertex mean."""
        n, m = len(self.V), len(self.F)
        A, B = [], []
        for i, f in enumerate(self.F):
            G = self.Gs[i]
            idx = [*f, n + i]
            s = np.sqrt(self.area[i])
            for c in range(3):
                row = np.zeros(n + m)
                for j in range(4):
                    row[idx[j]] += s * G[j, c]
                A.append(row)
                B.append(s * T[i][:, c])
        for v, t in rows:
            row = np.zeros(n + m)
            row[v] = np.sqrt(self.lam_p)
            A.append(row)
            B.append(np.sqrt(self.lam_p) * t)
        X = np.linalg.lstsq(np.array(A), np.array(B), rcond=None)[0][:n]
        if not rows:
            X += self.V.mean(0) - X.mean(0)
        return X

    def deform(self, hp, joints=None):
        w = self.weights(hp, joints)
        m = len(self.F)
        if self.ex:
            Q = [
                expm_rot(sum(w[k] * self.omega[k][e] for k in range(len(w))))
                for e in range(len(self.pairs))
            ]
            S = [sum(w[k] * self.S[k][i] for k in range(len(w))) for i in range(m)]
        else:
            Q = [np.eye(3)] * len(self.pairs)
            S = [np.eye(3)] * m
        links = self.links(Q, joints)
        R0 = self.chordal(links, [], {self.root})
        final_a = not self.handle_faces
        if not final_a:
            R0 = self.geodesic(links, R0, {self.root})
        x0 = self.positions([R0[i] @ S[i] for i in range(m)], [])
        t = np.concatenate(hp)
        G = kabsch(x0[self.Hall], t)
        if self.handle_faces:
            off = np.cumsum([0] + [len(h) for h in self.H])
            Gj = []
            for j, h in enumerate(self.H):
                ts = t[off[j] : off[j + 1]]
                ok = len(h) >= 3 and planarity(x0[h]) > 1e-6 and planarity(ts) > 1e-6
                Gj.append(kabsch(x0[h], ts) if ok else G)
            R = self.chordal(links, [(f, Gj[j] @ R0[f]) for f, j in self.handle_faces], set())
        else:
            R = np.array([G @ r for r in R0])
        return self.positions([R[i] @ S[i] for i in range(m)], list(zip(self.Hall, t, strict=True)))
