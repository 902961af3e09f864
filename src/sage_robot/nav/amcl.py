"""A particle filter equivalent to ROS AMCL (Thrun, Burgard, Fox, *Probabilistic Robotics*).

- Motion: the odometry model for a differential drive (``sample_motion_model_odometry``,
  table 5.6) with AMCL's ``alpha1..4``.
- Sensor: the likelihood field (:mod:`sage_robot.nav.likelihood`): each beam endpoint scores
  ``z_hit * N(d; 0, sigma_hit) + z_rand / range_max`` where ``d`` is the distance from the
  endpoint to the nearest occupied map cell (``scipy.ndimage.distance_transform_edt``).
  Beams are correlated, so the log-likelihood is tempered by ``BEAM_TEMPER``.
- KLD-adaptive particle count between ``min_particles`` and ``max_particles``
  (Fox 2003; AMCL's ``pf_err`` 0.01, ``pf_z`` 0.99) over 0.5 m × 0.5 m × 10° bins.
- Augmented MCL: ``w_slow``/``w_fast`` averages of the measurement likelihood; when the
  short-term fit drops below ``INJECT_RATIO`` of the long-term one, up to
  ``MAX_INJECT_FRACTION`` of the particles are redrawn uniformly over free space.
- Global localization (``amcl_global``): a lattice of poses over the reachable free space
  scored against the scan, the best refined, ``GLOBAL_PARTICLES`` kept; the particle cap
  stays raised until KLD sampling asks for no more than ``max_particles`` (the cloud has
  gathered), so several look-alike places stay alive while the robot drives.

Conventions: map frame, metres and radians; particles are an (N, 3) array of
(x, y, theta); weights sum to 1. Randomness only from the ``numpy.random.Generator``
given to the constructor.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sage_robot.core.geometry import compose, relative, wrap_angle, wrap_angles
from sage_robot.core.msgs import OccupancyGrid
from sage_robot.nav.amcl_global import (
    Hypothesis,
    equal_share_weights,
    global_poses,
    hypotheses,
    keep_alive,
    poses_in,
    search_region,
)
from sage_robot.nav.likelihood import BEAM_TEMPER, LikelihoodField, beam_log_likelihood

# AMCL alpha1..4: rot from rot, rot from trans, trans from trans, trans from rot
ALPHAS = (0.2, 0.2, 0.2, 0.2)
UPDATE_MIN_D_M = 0.25  # AMCL update_min_d
UPDATE_MIN_A_RAD = 0.2  # AMCL update_min_a
KLD_ERR, KLD_Z = 0.01, 2.326  # pf_err, z of the 0.99 quantile (AMCL pf_z)
KLD_BIN_M, KLD_BIN_RAD = 0.5, math.radians(10.0)
ALPHA_SLOW, ALPHA_FAST = 0.001, 0.1  # AMCL recovery_alpha_slow / _fast
GLOBAL_PARTICLES = 8000  # particle cap right after global localization; KLD brings it back to max
INIT_SIGMA_XY_M, INIT_SIGMA_YAW_RAD = 0.25, 0.2
CLUSTER_CELL_M = 0.5  # particles are grouped on this grid to find the heaviest cluster
CLUSTER_RADIUS_M = 1.0  # the estimate averages particles this close to that cluster
MAX_INJECT_FRACTION = 0.2  # at most this share of particles is redrawn at random per update
INJECT_RATIO = 0.5  # inject only once the short-term fit falls below this share of the long-term one
# A confident estimate (its cluster holds CONFIDENT_SHARE of the weight) stays with the particles
# near where it was, carried by the odometry, until another place has been heavier for
# SWITCH_UPDATES filter updates in a row (or the home keeps almost nothing): issue #20, in an open
# hall of willow-2010 the fit of the true pose fell (long, noisy returns), injected particles in
# a small room elsewhere fitted better for a moment, and the estimate jumped 20 m while it was
# exact; the robot then drove on a wrong pose and asked for help.
CONFIDENT_SHARE = 0.9
SWITCH_UPDATES = 8
HOME_MIN_SHARE = 0.02
MIN_JUDGED_RETURNS = 10  # the health score needs this many returns the map can judge (else NaN)
UNMAPPED_FROM_WALL_M = 0.5  # a return ending this far from every mapped wall, on free floor, with no
#   wall before it, hit something the map does not have and is not judged (nearer a wall it is)


@dataclass(frozen=True)
class Estimate:
    """Mean pose (x, y, theta) and its 3×3 covariance (row-major tuple)."""

    x: float
    y: float
    theta: float
    covariance: tuple[float, ...]


def kld_count(bins: int, n_min: int, n_max: int) -> int:
    """Particles needed so the KL divergence to the true posterior stays below KLD_ERR."""
    if bins <= 1:
        return n_min
    k = bins - 1
    b = 2.0 / (9.0 * k)
    n = k / (2.0 * KLD_ERR) * (1.0 - b + math.sqrt(b) * KLD_Z) ** 3
    return int(min(max(n, n_min), n_max))


def sample_odometry(particles: np.ndarray, prev: tuple[float, float, float],
                    cur: tuple[float, float, float], rng: np.random.Generator,
                    alphas: tuple[float, float, float, float] = ALPHAS) -> np.ndarray:
    """Move every particle by the odometry increment prev→cur (odom frame), with noise."""
    dx, dy = cur[0] - prev[0], cur[1] - prev[1]
    trans = math.hypot(dx, dy)
    rot1 = wrap_angle(math.atan2(dy, dx) - prev[2]) if trans > 0.01 else 0.0
    if abs(rot1) > math.pi / 2:  # moved backwards: model it as reversing, as AMCL does
        rot1 = wrap_angle(rot1 - math.pi)
        trans = -trans
    rot2 = wrap_angle(cur[2] - prev[2] - rot1)
    a1, a2, a3, a4 = alphas
    n = len(particles)
    # AMCL uses the smaller of the two rotation directions for the noise
    r1n = min(abs(rot1), abs(wrap_angle(rot1 - math.pi)))
    r2n = min(abs(rot2), abs(wrap_angle(rot2 - math.pi)))
    rot1_h = rot1 - rng.normal(0, math.sqrt(a1 * r1n**2 + a2 * trans**2), n)
    trans_h = trans - rng.normal(0, math.sqrt(a3 * trans**2 + a4 * (r1n**2 + r2n**2)), n)
    rot2_h = rot2 - rng.normal(0, math.sqrt(a1 * r2n**2 + a2 * trans**2), n)
    out: np.ndarray = particles.copy()
    heading = particles[:, 2] + rot1_h
    out[:, 0] += trans_h * np.cos(heading)
    out[:, 1] += trans_h * np.sin(heading)
    out[:, 2] = wrap_angles(particles[:, 2] + rot1_h + rot2_h)
    return out


class ParticleFilter:
    """AMCL. Call :meth:`set_pose` or :meth:`global_localization`, then :meth:`update` with each
    odometry pose and scan; :meth:`estimate` gives the mean and covariance."""

    def __init__(self, grid: OccupancyGrid, rng: np.random.Generator, min_particles: int = 500,
                 max_particles: int = 2000, sensor: tuple[float, float, float] = (0.0, 0.0, 0.0),
                 beams: int = 60, seeds: list[tuple[float, float]] | None = None,
                 global_particles: int = GLOBAL_PARTICLES) -> None:
        """``seeds``: map points (the places) inside the region the robot can be in; global
        localization and random particles stay in the free space connected to them."""
        if not 0 < min_particles <= max_particles:
            raise ValueError("need 0 < min_particles <= max_particles")
        self.field = LikelihoodField(grid)
        self.rng = rng
        self.n_min, self.n_max = min_particles, max_particles
        self.n_global = max(global_particles, max_particles)
        self._cap = max_particles  # raised to n_global by global localization until the cloud gathers
        self._seeds = list(seeds) if seeds else None
        self._region: np.ndarray | None = None
        self.sensor, self.beams = sensor, beams
        self.particles = np.zeros((min_particles, 3))
        self.weights = np.full(min_particles, 1.0 / min_particles)
        self.w_slow = self.w_fast = 0.0
        self._odom_ref: tuple[float, float, float] | None = None  # odometry at the last filter update
        self.updates = 0
        self.injected = 0
        self._centre: np.ndarray | None = None  # the cluster the estimate reports (None: the heaviest)
        self._home: tuple[float, float, float] | None = None  # a confident estimate at the last update
        self._rival = 0  # updates in a row another place was heavier than home

    # ---------------------------------------------------------------- initialization
    def set_pose(self, x: float, y: float, theta: float, sigma_xy: float = INIT_SIGMA_XY_M,
                 sigma_yaw: float = INIT_SIGMA_YAW_RAD) -> None:
        n = self.n_max
        self.particles = np.column_stack([
            self.rng.normal(x, sigma_xy, n), self.rng.normal(y, sigma_xy, n),
            wrap_angles(self.rng.normal(theta, sigma_yaw, n)),
        ])
        self.weights = np.full(n, 1.0 / n)
        self.w_slow = self.w_fast = 0.0
        self._cap = self.n_max
        self._forget_home()

    def _forget_home(self) -> None:
        self._centre, self._home, self._rival = None, None, 0

    @property
    def region(self) -> np.ndarray:
        """(row, col) cells the robot's centre may be in (see ``amcl_global.search_region``)."""
        if self._region is None:
            self._region = search_region(self.field, self._seeds)
        return self._region

    def random_poses(self, n: int) -> np.ndarray:
        """``n`` poses drawn uniformly over :attr:`region`, random headings."""
        return poses_in(self.field, self.region, n, self.rng)

    def global_localization(self, scan: tuple[np.ndarray, np.ndarray, float] | None = None) -> None:
        """Relocalize over the whole map. Without a scan, ``n_global`` poses uniformly over the
        region (AMCL's way); with one, the ``n_global`` poses that best explain it."""
        if scan is None:
            self.particles = self.random_poses(self.n_global)
        else:
            a, r, rmax = self._subsample(*scan, len(scan[0]))
            if len(r) == 0:
                self.particles = self.random_poses(self.n_global)
            else:
                self.particles = global_poses(self.field, self.region, self.n_global, self.sensor,
                                              a, r, rmax, self.rng)
        self._cap = self.n_global
        self.weights = equal_share_weights(self.particles)
        self.w_slow = self.w_fast = 0.0
        self._odom_ref = None
        self._forget_home()

    # ---------------------------------------------------------------- filtering
    def _subsample(self, angles: np.ndarray, ranges: np.ndarray, range_max: float,
                   beams: int) -> tuple[np.ndarray, np.ndarray, float]:
        ok = np.isfinite(ranges) & (ranges < range_max) & (ranges > 0)
        idx = np.flatnonzero(ok)
        if len(idx) > beams:
            idx = idx[np.linspace(0, len(idx) - 1, beams).astype(int)]
        return angles[idx].astype(np.float64), ranges[idx].astype(np.float64), range_max

    def moved_enough(self, odom: tuple[float, float, float]) -> bool:
        if self._odom_ref is None:
            return True
        ref = self._odom_ref
        return (math.hypot(odom[0] - ref[0], odom[1] - ref[1]) >= UPDATE_MIN_D_M
                or abs(wrap_angle(odom[2] - ref[2])) >= UPDATE_MIN_A_RAD)

    def update(self, odom: tuple[float, float, float], angles: np.ndarray, ranges: np.ndarray,
               range_max: float, force: bool = False) -> bool:
        """Motion + measurement + resampling, when the robot moved past AMCL's thresholds (or
        ``force``). ``odom`` is the odometry pose at the scan. Returns whether it updated."""
        if self._odom_ref is None:
            self._odom_ref = odom
            if not force:
                return False
        elif not (force or self.moved_enough(odom)):
            return False
        home = None if self._home is None else compose(self._home, relative(self._odom_ref, odom))
        self.particles = sample_odometry(self.particles, self._odom_ref, odom, self.rng)
        self._odom_ref = odom
        a, r, rmax = self._subsample(angles, ranges, range_max, self.beams)
        if len(r) == 0:
            return False
        loglik = beam_log_likelihood(self.field, self.particles, self.sensor, a, r, rmax)
        self._weigh(loglik, len(r))
        self._resample(loglik / len(r))
        self._choose(home)
        self.updates += 1
        return True

    def _choose(self, home: tuple[float, float, float] | None) -> None:
        """Which cluster the estimate reports from now on: the heaviest, except that a confident
        estimate stays home (see ``SWITCH_UPDATES``)."""
        p, w = self.particles, self.weights
        self._centre = None
        centre = self._heaviest_centre()
        anchored = False  # the estimate is (still) home
        if home is not None:
            at_home = np.hypot(p[:, 0] - home[0], p[:, 1] - home[1]) <= CLUSTER_RADIUS_M
            home_mass = float(w[at_home].sum())
            if math.hypot(centre[0] - home[0], centre[1] - home[1]) <= CLUSTER_RADIUS_M:
                self._rival, anchored = 0, True
            elif home_mass >= HOME_MIN_SHARE * float(w.sum()):
                rival = np.hypot(p[:, 0] - centre[0], p[:, 1] - centre[1]) <= CLUSTER_RADIUS_M
                self._rival = self._rival + 1 if float(w[rival].sum()) > home_mass else 0
                if self._rival < SWITCH_UPDATES:
                    centre = np.average(p[at_home, :2], axis=0, weights=w[at_home] + 1e-300)
                    anchored = True
        if not anchored:
            self._rival = 0
        self._centre = centre
        near = np.hypot(p[:, 0] - centre[0], p[:, 1] - centre[1]) <= CLUSTER_RADIUS_M
        confident = float(w[near].sum()) >= CONFIDENT_SHARE * float(w.sum())
        e = self.estimate()
        self._home = (e.x, e.y, e.theta) if (anchored or confident) else None

    def _weigh(self, loglik: np.ndarray, n_beams: int) -> None:
        logw = np.log(np.maximum(self.weights, 1e-300)) + BEAM_TEMPER * loglik
        logw -= logw.max()
        w = np.exp(logw)
        self.weights = w / w.sum()
        # per-beam average likelihood: comparable across scans with different beam counts
        w_avg = float(np.mean(np.exp(loglik / n_beams)))
        if self.w_slow == 0.0:
            self.w_slow = self.w_fast = w_avg
        else:
            self.w_slow += ALPHA_SLOW * (w_avg - self.w_slow)
            self.w_fast += ALPHA_FAST * (w_avg - self.w_fast)

    def _resample(self, loglik_per_beam: np.ndarray | None = None) -> None:
        n_old = len(self.particles)
        bins = np.floor(np.column_stack([
            self.particles[:, 0] / KLD_BIN_M, self.particles[:, 1] / KLD_BIN_M,
            self.particles[:, 2] / KLD_BIN_RAD])).astype(np.int64)
        k = len(np.unique(_key(bins)))
        n = kld_count(k, self.n_min, self._cap)
        if n <= self.n_max:
            self._cap = self.n_max  # the cloud has gathered: back to AMCL's max_particles
        # low-variance (systematic) resampling from q, which keeps runner-up hypotheses alive;
        # the drawn particles carry weight w/q so each hypothesis keeps its true share
        q, boost = keep_alive(self.particles, self.weights, loglik_per_beam)
        positions = (self.rng.random() + np.arange(n)) / n
        idx = np.minimum(np.searchsorted(np.cumsum(q), positions), n_old - 1)
        new = self.particles[idx]
        w = self.weights[idx] * boost[idx] / np.maximum(q[idx], 1e-300)
        p_inject = 0.0
        if self.w_slow > 0:
            p_inject = min(MAX_INJECT_FRACTION, max(0.0, 1.0 - self.w_fast / (INJECT_RATIO * self.w_slow)))
        inject = self.rng.random(n) < p_inject
        if inject.any():
            new[inject] = self.random_poses(int(inject.sum()))
            self.injected += int(inject.sum())
        if inject.any():
            w[inject] = float(np.mean(w))
        self.particles = new
        self.weights = w / w.sum()

    # ---------------------------------------------------------------- output
    def estimate(self) -> Estimate:
        """Mean and covariance of the heaviest cluster (as AMCL reports its best cluster, so
        injected random particles and far-away hypotheses do not drag the pose)."""
        p, w = self.particles, self.weights
        centre = self._heaviest_centre() if self._centre is None else self._centre
        near = np.hypot(p[:, 0] - centre[0], p[:, 1] - centre[1]) <= CLUSTER_RADIUS_M
        if not near.any():
            centre = self._heaviest_centre()
            near = np.hypot(p[:, 0] - centre[0], p[:, 1] - centre[1]) <= CLUSTER_RADIUS_M
        return _weighted_pose(p[near], w[near])

    def _heaviest_centre(self) -> np.ndarray:
        p, w = self.particles, self.weights
        cells = np.floor(p[:, :2] / CLUSTER_CELL_M).astype(np.int64)
        _, inverse = np.unique(_key(cells), return_inverse=True)
        inverse = inverse.ravel()
        mass = np.bincount(inverse, weights=w)
        best = inverse == int(np.argmax(mass))
        centre: np.ndarray = np.average(p[best, :2], axis=0, weights=w[best] + 1e-300)
        return centre

    def spread_m(self) -> float:
        """How far from converged the cloud is (m): the larger of the weighted root-mean-square
        distance of the heaviest hypothesis' particles from its centre and the distance from
        that centre to the farthest other hypothesis. A cloud split between two look-alike
        places is not converged, however tight each part; lone random particles do not count."""
        hyps = self.hypotheses()
        if not hyps:  # no cluster at all: particles scattered everywhere
            e = self.estimate()
            d2 = (self.particles[:, 0] - e.x) ** 2 + (self.particles[:, 1] - e.y) ** 2
            return float(np.sqrt(np.average(d2, weights=self.weights)))
        best = hyps[0]
        return max([best.rms_m, *(math.hypot(h.x - best.x, h.y - best.y) for h in hyps[1:])])

    def hypotheses(self) -> list[Hypothesis]:
        """The places the cloud still considers (see ``amcl_global.hypotheses``), heaviest first."""
        return hypotheses(self.particles, self.weights)

    def pose_at(self, odom: tuple[float, float, float]) -> tuple[float, float, float]:
        """The estimate carried forward by the odometry since the last filter update."""
        e = self.estimate()
        if self._odom_ref is None:
            return (e.x, e.y, e.theta)
        return compose((e.x, e.y, e.theta), relative(self._odom_ref, odom))

    @property
    def count(self) -> int:
        return len(self.particles)


def _key(cells: np.ndarray) -> np.ndarray:
    """One int64 per row of up to three small integer bin coordinates (each within ±2^19)."""
    out = np.zeros(len(cells), dtype=np.int64)
    for j in range(cells.shape[1]):
        out = out * (1 << 20) + (cells[:, j] + (1 << 19))
    return out


def _weighted_pose(p: np.ndarray, w: np.ndarray) -> Estimate:
    w = w / w.sum() if w.sum() > 0 else np.full(len(w), 1.0 / len(w))
    x, y = float(np.dot(w, p[:, 0])), float(np.dot(w, p[:, 1]))
    theta = math.atan2(float(np.dot(w, np.sin(p[:, 2]))), float(np.dot(w, np.cos(p[:, 2]))))
    d = p - np.array([x, y, theta])
    d[:, 2] = wrap_angles(d[:, 2])
    cov = (d * w[:, None]).T @ d
    return Estimate(x, y, theta, tuple(float(v) for v in cov.ravel()))


def scan_fit(field: LikelihoodField, pose: tuple[float, float, float], sensor: tuple[float, float, float],
             angles: np.ndarray, ranges: np.ndarray, range_max: float, tolerance_m: float) -> float:
    """Localization health: of the scan's returns the map can judge, the fraction (0..1) that
    land within ``tolerance_m`` of a mapped obstacle when the scan is placed at ``pose``.

    A return that ends on known-free floor, :data:`UNMAPPED_FROM_WALL_M` or more from every
    mapped wall, with no mapped wall before it along its beam, hit something the map does not
    have (a person, a box, a chair): it says nothing about the pose and is not judged, so a
    crowd round the robot, or a hall whose few mapped walls are far (most returns then come
    from people), leaves the score where the walls put it. A return past a mapped wall, near
    one, or in space the map does not know counts against: a wrong pose lowers the score a
    lot. NaN when fewer than :data:`MIN_JUDGED_RETURNS` can be judged."""
    ok = np.isfinite(ranges) & (ranges > 0) & (ranges < range_max)
    if not ok.any():
        return float("nan")
    sx, sy, st = sensor
    x, y, t = pose
    c, s = math.cos(t), math.sin(t)
    ox, oy = x + c * sx - s * sy, y + s * sx + c * sy
    a, r = t + st + angles[ok], ranges[ok]
    ex, ey = ox + r * np.cos(a), oy + r * np.sin(a)
    d = field.distances(ex, ey)
    fits = d <= tolerance_m
    rest = np.flatnonzero(d > UNMAPPED_FROM_WALL_M)
    free = rest[field.on_free(ex[rest], ey[rest])]
    unmapped = free[~field.crosses_wall(ox, oy, a[free], r[free] - tolerance_m)]
    judged = len(r) - len(unmapped)
    if judged < MIN_JUDGED_RETURNS:
        return float("nan")
    return float(np.count_nonzero(fits) / judged)
