"""A 2D pose graph and its sparse Levenberg-Marquardt optimiser (scipy.sparse + SuperLU).

Nodes are poses ``x_i = (x, y, theta)`` in the map frame (m, rad). An edge (i, j) holds a
measured relative pose ``z`` (the pose of j in the frame of i) and its 3x3 information
matrix. The error of an edge is ``e = t2v(Z⁻¹ · X_i⁻¹ · X_j)`` with analytic Jacobians
(Grisetti et al., "A tutorial on graph-based SLAM"). Loop-closure edges get a Huber kernel
by iteratively re-weighting, so one false match bends the map less. Node 0 is held fixed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import spsolve

from sage_robot.nav.slam.points import Pose

HUBER_CHI = 3.0  # loop-closure edges with a Mahalanobis error beyond this are down-weighted
LM_LAMBDA0 = 1e-4  # initial Levenberg-Marquardt damping (relative to the diagonal)
ANCHOR_INFO = 1e9  # information that fixes node 0

KIND_ODOM, KIND_SCAN, KIND_LOOP = "odom", "scan", "loop"


@dataclass
class Edge:
    i: int
    j: int
    z: Pose  # pose of node j in the frame of node i (m, rad)
    information: np.ndarray  # 3x3, of (x, y, theta)
    kind: str = KIND_SCAN


@dataclass
class PoseGraph:
    poses: list[Pose] = field(default_factory=list)
    edges: list[Edge] = field(default_factory=list)

    def add_node(self, pose: Pose) -> int:
        self.poses.append(pose)
        return len(self.poses) - 1

    def add_edge(self, i: int, j: int, z: Pose, information: np.ndarray, kind: str = KIND_SCAN) -> None:
        if not (0 <= i < len(self.poses) and 0 <= j < len(self.poses)) or i == j:
            raise ValueError(f"edge ({i}, {j}) needs two different existing nodes")
        self.edges.append(Edge(i, j, z, np.asarray(information, dtype=np.float64), kind))

    @property
    def loop_closures(self) -> int:
        return sum(1 for e in self.edges if e.kind == KIND_LOOP)

    def as_array(self) -> np.ndarray:
        return np.array(self.poses, dtype=np.float64).reshape(-1, 3)

    # ------------------------------------------------------------------ optimisation
    def _linearise(
        self, x: np.ndarray, sqrt_info: np.ndarray, robust: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Whitened residuals, per-edge robust weights and the blocks A (d/dxi), B (d/dxj)."""
        ii = np.array([e.i for e in self.edges])
        jj = np.array([e.j for e in self.edges])
        z = np.array([e.z for e in self.edges], dtype=np.float64)
        ti, tj = x[ii, :2], x[jj, :2]
        thi, thj = x[ii, 2], x[jj, 2]
        ci, si = np.cos(thi), np.sin(thi)
        cz, sz = np.cos(z[:, 2]), np.sin(z[:, 2])
        d = tj - ti
        # Ri^T d, then Rz^T (Ri^T d - tz)
        lx = ci * d[:, 0] + si * d[:, 1]
        ly = -si * d[:, 0] + ci * d[:, 1]
        ux, uy = lx - z[:, 0], ly - z[:, 1]
        e = np.column_stack(
            (cz * ux + sz * uy, -sz * ux + cz * uy, (thj - thi - z[:, 2] + math.pi) % (2 * math.pi) - math.pi)
        )
        m = len(self.edges)
        # RzT RiT
        rr = np.empty((m, 2, 2))
        c, s = np.cos(thi + z[:, 2]), np.sin(thi + z[:, 2])
        rr[:, 0, 0], rr[:, 0, 1], rr[:, 1, 0], rr[:, 1, 1] = c, s, -s, c
        # d(RzT RiT d)/dthi = RzT dRiT/dthi d = RzT (ly, -lx)
        dth = np.column_stack((cz * ly - sz * lx, -sz * ly - cz * lx))
        a = np.zeros((m, 3, 3))
        b = np.zeros((m, 3, 3))
        a[:, :2, :2] = -rr
        a[:, :2, 2] = dth
        a[:, 2, 2] = -1.0
        b[:, :2, :2] = rr
        b[:, 2, 2] = 1.0
        r = np.einsum("mab,mb->ma", sqrt_info, e)
        chi = np.linalg.norm(r, axis=1)
        w = np.where(robust & (chi > HUBER_CHI), np.sqrt(HUBER_CHI / np.maximum(chi, 1e-12)), 1.0)
        r = r * w[:, None]
        wa = np.einsum("mab,mbc->mac", sqrt_info, a) * w[:, None, None]
        wb = np.einsum("mab,mbc->mac", sqrt_info, b) * w[:, None, None]
        return r, wa, wb, chi

    def optimize(self, iterations: int = 20, tolerance: float = 1e-6) -> dict[str, float]:
        """Optimise every pose but node 0 in place. Returns the initial and final cost."""
        n = len(self.poses)
        if n < 2 or not self.edges:
            return {"iterations": 0, "initial_cost": 0.0, "final_cost": 0.0}
        x = self.as_array()
        sqrt_info = np.array([_sqrt_info(e.information) for e in self.edges])
        robust = np.array([e.kind == KIND_LOOP for e in self.edges])
        ii = np.array([e.i for e in self.edges])
        jj = np.array([e.j for e in self.edges])
        m = len(self.edges)
        # Entry (a, b) of edge k's blocks sits at row 3k + a and column 3i + b (A) or 3j + b (B).
        rows = (3 * np.arange(m)[:, None, None] + np.arange(3)[None, :, None]) + np.zeros((1, 1, 3), int)
        cols_i = 3 * ii[:, None, None] + np.arange(3)[None, None, :] + np.zeros((1, 3, 1), int)
        cols_j = 3 * jj[:, None, None] + np.arange(3)[None, None, :] + np.zeros((1, 3, 1), int)
        rows_all = np.concatenate((rows.ravel(), rows.ravel()))
        cols_all = np.concatenate((cols_i.ravel(), cols_j.ravel()))

        def cost_of(xx: np.ndarray) -> float:
            r, *_ = self._linearise(xx, sqrt_info, robust)
            return float((r**2).sum())

        lam = LM_LAMBDA0
        r, wa, wb, _ = self._linearise(x, sqrt_info, robust)
        cost0 = cost = float((r**2).sum())
        done = 0
        for _ in range(iterations):
            done += 1
            jac = sp.csr_matrix(
                (np.concatenate((wa.ravel(), wb.ravel())), (rows_all, cols_all)), shape=(3 * m, 3 * n)
            )
            h = (jac.T @ jac).tocsc()
            g = jac.T @ r.ravel()
            h = h + sp.diags(np.r_[np.full(3, ANCHOR_INFO), np.zeros(3 * n - 3)])
            diag = h.diagonal()
            improved = False
            while lam < 1e8:
                step = spsolve(h + sp.diags(lam * np.maximum(diag, 1e-9)), -g)
                x_new = x + step.reshape(n, 3)
                x_new[:, 2] = (x_new[:, 2] + math.pi) % (2 * math.pi) - math.pi
                c_new = cost_of(x_new)
                if c_new < cost:
                    x, lam, improved = x_new, max(lam / 10.0, 1e-9), True
                    break
                lam *= 10.0
            if not improved:
                break
            rel = (cost - c_new) / max(cost, 1e-12)
            cost = c_new
            r, wa, wb, _ = self._linearise(x, sqrt_info, robust)
            if rel < tolerance:
                break
        self.poses = [(float(p[0]), float(p[1]), float(p[2])) for p in x]
        return {"iterations": done, "initial_cost": cost0, "final_cost": cost}

    def edge_errors(self) -> np.ndarray:
        """Mahalanobis error of every edge at the current poses."""
        if not self.edges:
            return np.zeros(0)
        sqrt_info = np.array([_sqrt_info(e.information) for e in self.edges])
        _, _, _, chi = self._linearise(self.as_array(), sqrt_info, np.zeros(len(self.edges), dtype=bool))
        return chi


def _sqrt_info(info: np.ndarray) -> np.ndarray:
    """U with UᵀU = info (for a positive semi-definite info, via eigen-decomposition)."""
    vals, vecs = np.linalg.eigh(0.5 * (info + info.T))
    u: np.ndarray = (vecs * np.sqrt(np.maximum(vals, 0.0))).T
    return u
