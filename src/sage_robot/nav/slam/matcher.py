"""Scan-to-map matching: a correlative search (coarse-to-fine, vectorised over a precomputed
likelihood field) followed by point-to-line ICP (Gauss-Newton) against the map's points.

A :class:`PointMap` holds map-frame points (m) with their normals, a KD-tree, and a
likelihood field: ``L = exp(-d² / 2σ²)`` of the distance ``d`` (m) to the nearest map point,
on a grid of ``grid_res`` (m) cells, row = y, column = x. A second field holds, per cell,
the maximum of ``L`` over the ``COARSE`` × ``COARSE`` cells above and to its right: the
score of one coarse offset bounds the scores of every fine offset inside it, so the search
looks at fine offsets only inside the best coarse ones (branch and bound of depth two, as
Olson's real-time correlative scan matching and Cartographer do).

With ``oriented`` normals (each pointing toward the sensor that saw its point) ICP pairs a
scan point only with a map surface that faces the scan's sensor: the two faces of a 20 cm
wall, one seen through a door on the way in and the other on the way out, are not confused.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import distance_transform_edt
from scipy.spatial import cKDTree

from sage_robot.nav.slam.points import Pose, normals, transform

COARSE = 4  # fine cells per coarse search step
MAX_LOOKUPS = 3_000_000  # field look-ups per vectorised batch (memory bound)
MAX_BRANCHES = 12  # coarse candidates refined at most
MIN_MATCH_POINTS = 10  # fewer scan points than this: no match
GATE_SIGMAS = 2.5  # association gates widen by this many range-noise sigmas


def smooth_normals(
    pts: np.ndarray, tree: cKDTree, oriented: np.ndarray, k: int, radius_m: float
) -> np.ndarray:
    """Normals of ``pts`` fitted to ``k`` neighbours within ``radius_m`` (a noisy lidar's walls
    are bands: few neighbours give tilted normals, which ICP takes for features along a bare
    wall), each turned to the side of the given ``oriented`` normal."""
    dist, idx = tree.query(pts, k=min(k, len(pts)), distance_upper_bound=radius_m)
    valid = np.isfinite(dist)
    idx = np.where(valid, idx, np.arange(len(pts))[:, None])
    w = valid.astype(np.float64)
    cnt = np.maximum(w.sum(axis=1), 1.0)
    nb = pts[idx]
    mean = (nb * w[:, :, None]).sum(axis=1) / cnt[:, None]
    d = (nb - mean[:, None, :]) * w[:, :, None]
    sxx, syy = (d[:, :, 0] ** 2).sum(axis=1), (d[:, :, 1] ** 2).sum(axis=1)
    sxy = (d[:, :, 0] * d[:, :, 1]).sum(axis=1)
    angle = 0.5 * np.arctan2(2.0 * sxy, sxx - syy) + np.pi / 2.0
    out = np.column_stack((np.cos(angle), np.sin(angle)))
    out[cnt < 3] = oriented[cnt < 3]
    flip = np.einsum("ij,ij->i", out, oriented) < 0
    out[flip] *= -1.0
    return out


@dataclass(frozen=True)
class MatchConfig:
    grid_res_m: float = 0.1  # likelihood field cell size (m): coarse, ICP refines
    sigma_m: float = 0.1  # likelihood fall-off with distance to the nearest map point
    icp_stages_m: tuple[float, ...] = (0.25, 0.1)  # association gates (m), coarse to fine
    icp_iterations: int = 6  # Gauss-Newton steps per stage
    huber_m: float = 0.03  # residuals beyond this are down-weighted
    inlier_m: float = 0.08  # a scan point this close to the map counts as matched
    point_sigma_m: float = 0.01  # residual noise per point for the match's information
    # Range noise of the lidar as a fraction of the range (RPLIDAR A1M8: 0.01; 0 = none beyond
    # point_sigma_m): far points then weigh less and get wider association gates.
    range_noise_fraction: float = 0.0
    # > 0 (with range_noise_fraction): a match whose information is at least this isotropic (x, y:
    # weakest over strongest direction) is refined again with every pairing weighing the same.
    # Where the scan pins the pose down in every direction the far returns' noise cannot pull it
    # along a corridor, and the near returns, which the range weights make decide the match, read
    # the travel long (docs/slam.md, "Equal weights where the scan pins the pose"). The match's
    # information stays the range-weighted one.
    equal_weights_isotropy: float = 0.0


def isotropy(information: np.ndarray) -> float:
    """Weakest over strongest direction of the x, y part of an (x, y, theta) information
    matrix: 0 along a bare corridor, 1 in a room that pins the position equally every way."""
    vals = np.linalg.eigvalsh(information[:2, :2])
    return float(vals[0] / vals[1]) if vals[1] > 0 else 0.0


@dataclass(frozen=True)
class Match:
    pose: Pose  # map frame (m, rad)
    score: float  # mean likelihood of the scan points, 0..1
    inliers: float  # fraction of scan points within inlier_m of the map
    information: np.ndarray  # 3x3, of (x, y, theta), per unit weight of one scan
    equal_weights: bool = False  # refined with every pairing weighing the same (equal_weights_isotropy)


class PointMap:
    """Map-frame points to match against. ``margin_m`` bounds the search window."""

    def __init__(
        self,
        pts: np.ndarray,
        config: MatchConfig,
        margin_m: float = 1.0,
        point_normals: np.ndarray | None = None,
        oriented: bool = False,
    ) -> None:
        self.config = config
        self.oriented = oriented and point_normals is not None  # normals face their sensors
        self.points = pts
        self.tree = cKDTree(pts)
        self.normals = normals(pts, self.tree) if point_normals is None else point_normals
        self.margin_m = margin_m
        self._field: np.ndarray | None = None
        self._coarse: np.ndarray | None = None
        self.last_second_best = 0.0

    # ---------------------------------------------------------------- likelihood field
    def _build_field(self) -> None:
        res = self.config.grid_res_m
        pad = math.ceil(self.margin_m / res) + 2 * COARSE + 2
        lo = self.points.min(axis=0) - pad * res
        hi = self.points.max(axis=0) + pad * res
        shape = (math.ceil((hi[1] - lo[1]) / res) + 1, math.ceil((hi[0] - lo[0]) / res) + 1)
        occ = np.zeros(shape, dtype=bool)
        cells = np.floor((self.points - lo) / res).astype(np.int64)
        occ[cells[:, 1], cells[:, 0]] = True
        dist = distance_transform_edt(~occ) * res
        field = np.exp(-0.5 * (dist / self.config.sigma_m) ** 2).astype(np.float32)
        border = 1 + COARSE
        field[:border, :] = field[-border:, :] = 0.0
        field[:, :border] = field[:, -border:] = 0.0
        coarse = field.copy()
        for axis in (0, 1):
            src = coarse.copy()
            for k in range(1, COARSE):
                if axis == 0:
                    np.maximum(coarse[:-k, :], src[k:, :], out=coarse[:-k, :])
                else:
                    np.maximum(coarse[:, :-k], src[:, k:], out=coarse[:, :-k])
        self._origin, self._field, self._coarse = lo, field, coarse

    def field(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if self._field is None:
            self._build_field()
        assert self._field is not None  # built just above
        assert self._coarse is not None
        return self._origin, self._field, self._coarse

    def _base_cells(self, q: np.ndarray, x: float, y: float, thetas: np.ndarray) -> np.ndarray:
        """Flat field index of each rotated scan point at translation (x, y): (angles, points)."""
        origin, field, _ = self.field()
        res = self.config.grid_res_m
        c, s = np.cos(thetas)[:, None], np.sin(thetas)[:, None]
        px = c * q[:, 0] - s * q[:, 1] + (x - origin[0])
        py = s * q[:, 0] + c * q[:, 1] + (y - origin[1])
        h, w = field.shape
        ix = np.clip(np.floor(px / res).astype(np.int64), 0, w - 1)
        iy = np.clip(np.floor(py / res).astype(np.int64), 0, h - 1)
        cells: np.ndarray = iy * w + ix
        return cells

    def score(self, q: np.ndarray, pose: Pose) -> float:
        """Mean likelihood of the robot-frame points ``q`` at ``pose`` (0..1)."""
        _, field, _ = self.field()
        idx = self._base_cells(q, pose[0], pose[1], np.array([pose[2]]))[0]
        return float(field.ravel()[idx].mean()) if len(q) else 0.0

    # ---------------------------------------------------------------- correlative search
    def search(
        self,
        q: np.ndarray,
        prior: Pose,
        window_xy_m: float,
        window_theta: float,
        theta_step: float,
        distinct_m: float = 0.0,
        prior_sigma: tuple[float, float] | None = None,
    ) -> tuple[Pose, float]:
        """Best pose of the robot-frame points ``q`` within ±window of ``prior`` on the field grid.

        Returns the pose and its score (mean likelihood). Exact on the grid: a coarse block is
        refined while its upper bound beats the best fine score (up to MAX_BRANCHES blocks).
        With ``distinct_m`` > 0, ``last_second_best`` is then the best score of poses more than
        that far (m) from the best one: close to the best score means an ambiguous match.
        ``prior_sigma`` = (m, rad) weighs each candidate by a Gaussian of its distance from the
        prior (as Cartographer's real-time matcher), so a bare corridor keeps the prediction.
        """
        _, field, coarse = self.field()
        res = self.config.grid_res_m
        width = field.shape[1]
        half = min(math.ceil(window_xy_m / res), int(self.margin_m / res))
        n_th = round(window_theta / theta_step)
        thetas = prior[2] + theta_step * np.arange(-n_th, n_th + 1)
        base = self._base_cells(q, prior[0], prior[1], thetas)  # (A, N)
        steps = np.arange(-half, half + 1, COARSE)
        cy, cx = np.meshgrid(steps, steps, indexing="ij")
        offsets = (cy * width + cx).ravel()
        flat_coarse, flat_field = coarse.ravel(), field.ravel()
        bounds = np.empty((len(thetas), len(offsets)), dtype=np.float32)
        batch = max(1, MAX_LOOKUPS // max(1, q.shape[0] * len(offsets)))
        for a0 in range(0, len(thetas), batch):
            idx = base[a0 : a0 + batch, :, None] + offsets[None, None, :]
            bounds[a0 : a0 + batch] = np.take(flat_coarse, idx, mode="clip").mean(axis=1)
        fy, fx = np.meshgrid(np.arange(COARSE), np.arange(COARSE), indexing="ij")
        fine = (fy * width + fx).ravel()
        w_angle = np.ones(len(thetas))
        w_fine = np.ones((len(offsets), COARSE * COARSE))
        if prior_sigma is not None:
            sxy, sth = prior_sigma
            w_angle = np.exp(-0.5 * ((thetas - prior[2]) / sth) ** 2)
            ddx = cx.ravel()[:, None] + fx.ravel()[None, :]
            ddy = cy.ravel()[:, None] + fy.ravel()[None, :]
            w_fine = np.exp(-0.5 * (np.hypot(ddx, ddy) * res / sxy) ** 2)
            bounds *= (w_angle[:, None] * w_fine.max(axis=1)[None, :]).astype(np.float32)

        def branch(bounds: np.ndarray) -> tuple[float, int, int, int]:
            best, best_a, best_o, best_i = -1.0, 0, 0, 0
            order = np.argsort(bounds, axis=None)[::-1]
            for _k, flat in enumerate(order[:MAX_BRANCHES]):
                a, o = divmod(int(flat), len(offsets))
                if bounds[a, o] <= best:
                    break
                cells = base[a][:, None] + offsets[o] + fine[None, :]
                scores = np.take(flat_field, cells, mode="clip").mean(axis=0) * w_angle[a] * w_fine[o]
                i = int(np.argmax(scores))
                if scores[i] > best:
                    best, best_a, best_o, best_i = float(scores[i]), a, o, i
            return best, best_a, best_o, best_i

        best, a, o, i = branch(bounds)
        dy = cy.ravel()[o] + fy.ravel()[i]
        dx = cx.ravel()[o] + fx.ravel()[i]
        best_pose = (prior[0] + dx * res, prior[1] + dy * res, float(thetas[a]))
        self.last_second_best = 0.0
        if distinct_m > 0:  # the best score of poses at least distinct_m away: ambiguity
            far = np.hypot(cx.ravel() - dx, cy.ravel() - dy) * res > distinct_m
            self.last_second_best = max(branch(np.where(far[None, :], bounds, -1.0))[0], 0.0)
        return best_pose, max(best, 0.0)

    # ---------------------------------------------------------------- refinement
    def _facing(self, pose: np.ndarray | Pose, viewpoint: tuple[float, float], p: np.ndarray,
                j: np.ndarray) -> np.ndarray:
        """Mask of map points ``j`` (paired with map-frame scan points ``p``) whose surface faces
        the sensor at robot-frame ``viewpoint`` when the robot is at ``pose`` (all True unless
        the normals are oriented)."""
        if not self.oriented:
            return np.ones(len(j), dtype=bool)
        sensor = transform(pose, np.array([viewpoint], dtype=np.float64))[0]
        facing: np.ndarray = np.einsum("ij,ij->i", self.normals[j], sensor - p) > 0.0
        return facing

    def _gates(
        self, q: np.ndarray, viewpoint: tuple[float, float], gate: float, equal: bool = False
    ) -> tuple[np.ndarray, np.ndarray]:
        """Per point: association gate (m) and weight (1 = a point with point_sigma_m noise;
        ``equal``: 1 for every point)."""
        cfg = self.config
        noise = cfg.range_noise_fraction * np.hypot(q[:, 0] - viewpoint[0], q[:, 1] - viewpoint[1])
        weight: np.ndarray = cfg.point_sigma_m**2 / (cfg.point_sigma_m**2 + noise**2)
        return np.hypot(gate, GATE_SIGMAS * noise), np.ones(len(q)) if equal else weight

    def _associate(
        self,
        x: np.ndarray | Pose,
        q: np.ndarray,
        viewpoint: tuple[float, float],
        gate: float,
        equal: bool = False,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Map-frame points, pairing mask, map indices and weights of the scan points ``q``."""
        p = transform(x, q)
        if self.config.range_noise_fraction > 0:
            gates, weight = self._gates(q, viewpoint, gate, equal)
            dist, j = self.tree.query(p, distance_upper_bound=float(gates.max()))
            ok = np.isfinite(dist) & (dist < gates)
        else:
            dist, j = self.tree.query(p, distance_upper_bound=gate)
            ok, weight = np.isfinite(dist), np.ones(len(q))
        ok[ok] = self._facing(x, viewpoint, p[ok], j[ok])
        return p, ok, j, weight

    def refine(
        self,
        q: np.ndarray,
        init: Pose,
        prior: Pose | None = None,
        prior_info: np.ndarray | None = None,
        viewpoint: tuple[float, float] = (0.0, 0.0),
    ) -> Match:
        """Point-to-line ICP from ``init``; an optional Gaussian ``prior`` keeps directions the
        map does not constrain (a long corridor) near the prediction. ``viewpoint``: the
        sensor's position in the robot frame (m), for oriented normals."""
        cfg = self.config
        match = self._evaluate(q, self._icp(q, init, prior, prior_info, viewpoint, False), viewpoint)
        if (
            cfg.equal_weights_isotropy > 0
            and cfg.range_noise_fraction > 0
            and isotropy(match.information) >= cfg.equal_weights_isotropy
        ):
            pose = self._icp(q, match.pose, prior, prior_info, viewpoint, True)
            match = dataclasses.replace(self._evaluate(q, pose, viewpoint), equal_weights=True)
        return match

    def _icp(
        self,
        q: np.ndarray,
        init: Pose,
        prior: Pose | None,
        prior_info: np.ndarray | None,
        viewpoint: tuple[float, float],
        equal: bool,
    ) -> Pose:
        """Gauss-Newton point-to-line ICP over the gates of ``icp_stages_m``; ``equal``: every
        pairing weighs the same (else by its range noise)."""
        cfg = self.config
        x = np.array(init, dtype=np.float64)
        jac = np.zeros((len(q), 3))
        for gate in cfg.icp_stages_m:
            for _ in range(cfg.icp_iterations):
                c, s = math.cos(x[2]), math.sin(x[2])
                p, ok, j, weight = self._associate(x, q, viewpoint, gate, equal)
                if ok.sum() < MIN_MATCH_POINTS:
                    break
                n = self.normals[j[ok]]
                r = np.einsum("ij,ij->i", n, p[ok] - self.points[j[ok]])
                qk = q[ok]
                jac = np.column_stack(
                    (
                        n[:, 0],
                        n[:, 1],
                        n[:, 0] * (-s * qk[:, 0] - c * qk[:, 1]) + n[:, 1] * (c * qk[:, 0] - s * qk[:, 1]),
                    )
                )
                wk = weight[ok]
                w = np.minimum(1.0, cfg.huber_m / np.sqrt(wk) / np.maximum(np.abs(r), 1e-12)) * wk
                inv_var = 1.0 / cfg.point_sigma_m**2
                h = jac.T @ (jac * w[:, None]) * inv_var
                g = jac.T @ (w * r) * inv_var
                if prior is not None and prior_info is not None:
                    d = x - np.asarray(prior)
                    d[2] = (d[2] + math.pi) % (2 * math.pi) - math.pi
                    h = h + prior_info
                    g = g + prior_info @ d
                try:
                    step = -np.linalg.solve(h + 1e-9 * np.eye(3), g)
                except np.linalg.LinAlgError:
                    break
                x += step
                if abs(step[0]) + abs(step[1]) < 1e-5 and abs(step[2]) < 1e-5:
                    break
        return (float(x[0]), float(x[1]), float((x[2] + math.pi) % (2 * math.pi) - math.pi))

    def _evaluate(self, q: np.ndarray, pose: Pose, viewpoint: tuple[float, float] = (0.0, 0.0)) -> Match:
        cfg = self.config
        c, s = math.cos(pose[2]), math.sin(pose[2])
        _, ok, j, weight = self._associate(pose, q, viewpoint, cfg.inlier_m)
        info = np.zeros((3, 3))
        if ok.sum() >= MIN_MATCH_POINTS:
            n, qk = self.normals[j[ok]], q[ok]
            jac = np.column_stack(
                (
                    n[:, 0],
                    n[:, 1],
                    n[:, 0] * (-s * qk[:, 0] - c * qk[:, 1]) + n[:, 1] * (c * qk[:, 0] - s * qk[:, 1]),
                )
            )
            info = (jac.T @ (jac * weight[ok][:, None])) / len(qk) / cfg.point_sigma_m**2
        score = self.score(q, pose) if self._field is not None else float(ok.mean())
        return Match(pose, score, float(ok.mean()) if len(q) else 0.0, info)
