"""Global localization for the particle filter: where on the whole map could this scan be?

AMCL's ``global_localization`` draws particles uniformly over free space and waits for the
robot to move. On a 100 m × 80 m building 2000 uniform particles leave ~1.6 m² each, so the
true pose usually has no particle near it and the filter locks onto a look-alike. Here:

1. **Region**: free cells at least ``CLEARANCE_M`` from any wall (the robot's centre cannot
   be closer), and, when ``seeds`` (the places) are given, only the connected pieces of
   free space that hold a place: the free "outside" of a drawn building is never searched.
2. **Coarse search**: a lattice of positions every ``LATTICE_M`` (jittered) × ``HEADINGS``
   headings, scored with ``COARSE_BEAMS`` beams against a likelihood field blurred to
   ``COARSE_SIGMA_M`` (so a pose half a lattice step off still scores well).
3. **Refinement**: the best ``REFINE_KEEP`` poses climb the sharp likelihood (AMCL's σ)
   with ``REFINE_ROUNDS`` rounds of shrinking random steps, keeping each step that helps.
4. The best ``n`` refined poses become the particles.

:func:`hypotheses` groups a particle cloud into the places it still considers (connected
``HYPOTHESIS_CELL_M`` cells), so a cloud split between two look-alike corridors is seen as
ambiguous, not as converged on the heavier one; :func:`keep_alive` makes the resampling
keep particles on each runner-up until the evidence has really ruled it out.

Conventions: map frame, metres, radians; poses are (N, 3) arrays of (x, y, theta).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from sage_robot.core.geometry import wrap_angles
from sage_robot.nav.likelihood import SIGMA_HIT_M, LikelihoodField, beam_log_likelihood

CLEARANCE_M = 0.2  # candidate positions keep this far from walls (robot radius 0.25 m)
LATTICE_M = 0.4  # coarse grid of candidate positions (m)
HEADINGS = 36  # coarse headings per position (10° apart)
COARSE_BEAMS = 24
COARSE_SIGMA_M = 0.5  # blurred likelihood for the coarse search (m)
REFINE_KEEP = 30_000  # coarse winners that are refined
REFINE_BEAMS = 36
REFINE_ROUNDS = 6
REFINE_STEP_XY_M = (0.2, 0.15, 0.1, 0.07, 0.05, 0.03)  # per round
REFINE_STEP_YAW_RAD = tuple(math.radians(d) for d in (5.0, 4.0, 3.0, 2.0, 1.5, 1.0))
HYPOTHESIS_CELL_M = 1.0  # particles are binned on this grid; touching bins form one hypothesis
HYPOTHESIS_MIN_SHARE = 1e-3  # a hypothesis holds at least this share of the weight ...
HYPOTHESIS_MIN_PARTICLES = 10  # ... and this many particles (injected strays do not count)
HYPOTHESIS_CELL_MIN = 2  # bins with fewer particles (lone injected ones) are ignored
HEADING_SECTORS = 8  # a place's particles are split into hypotheses by heading (45° sectors)
KEEP_SHARE = 0.05  # particles each runner-up hypothesis keeps at resampling (share of the cloud) ...
KEEP_BUDGET = 0.5  # ... while all runner-ups together take at most this share
KEEP_MIN_WEIGHT = HYPOTHESIS_MIN_SHARE  # a runner-up whose weight share falls below this is let go
KEEP_MAX = 24  # runner-up hypotheses kept alive at most
AMBIGUOUS_LL_PER_BEAM = 0.06  # a runner-up whose best particle fits this close to the leader's stays ...
AMBIGUOUS_SHARE = 2 * HYPOTHESIS_MIN_SHARE  # ... with at least this share of the weight
CHUNK = 16_384  # poses scored per batch (bounds memory: CHUNK × beams endpoints)


def search_region(field: LikelihoodField, seeds: list[tuple[float, float]] | None = None,
                  clearance_m: float = CLEARANCE_M) -> np.ndarray:
    """(K, 2) int array of (row, col) cells where the robot's centre may be.

    Free cells ``clearance_m`` or more from walls; with ``seeds`` (world x, y), only the
    connected components that contain a seed (or the cell nearest to it). Falls back to
    all free cells when nothing is that clear."""
    free = np.zeros(field.dist.shape, dtype=bool)
    free[field.free_cells[:, 0], field.free_cells[:, 1]] = True
    clear = free & (field.dist >= clearance_m)
    if not clear.any():
        return field.free_cells
    if seeds:
        labels, _ = ndimage.label(clear)
        keep: set[int] = set()
        rows, cols = np.nonzero(clear)
        for sx, sy in seeds:
            rr, cc = field.geom.to_cell(sx, sy)
            r, c = int(rr), int(cc)
            if 0 <= r < clear.shape[0] and 0 <= c < clear.shape[1] and clear[r, c]:
                keep.add(int(labels[r, c]))
            else:  # a place drawn on a wall or just off the map: its nearest clear cell
                k = int(np.argmin((rows - r) ** 2 + (cols - c) ** 2))
                keep.add(int(labels[rows[k], cols[k]]))
        clear &= np.isin(labels, sorted(keep))
    return np.argwhere(clear)


def poses_in(field: LikelihoodField, cells: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` poses uniformly over ``cells`` ((row, col) array), random headings."""
    idx = rng.integers(0, len(cells), n)
    rc = cells[idx].astype(np.float64) + rng.random((n, 2))
    g = field.geom
    return np.column_stack([g.origin_x + rc[:, 1] * g.resolution, g.origin_y + rc[:, 0] * g.resolution,
                            rng.uniform(-math.pi, math.pi, n)])


def _lattice(field: LikelihoodField, cells: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One position per ``LATTICE_M`` square that holds region cells, at a random region cell
    of that square (jitter that stays inside the region) → (M, 2) x, y."""
    g = field.geom
    step = max(1, round(LATTICE_M / g.resolution))
    block = cells // step
    key = block[:, 0] * (int(block[:, 1].max()) + 1) + block[:, 1]
    order = np.argsort(key, kind="stable")
    _, start, count = np.unique(key[order], return_index=True, return_counts=True)
    pick = cells[order[start + (rng.random(len(start)) * count).astype(np.int64)]]
    xy = pick.astype(np.float64) + rng.random((len(pick), 2))
    return np.column_stack([g.origin_x + xy[:, 1] * g.resolution, g.origin_y + xy[:, 0] * g.resolution])


def _score(field: LikelihoodField, poses: np.ndarray, sensor: tuple[float, float, float],
           angles: np.ndarray, ranges: np.ndarray, range_max: float, sigma: float) -> np.ndarray:
    out = np.empty(len(poses))
    for s in range(0, len(poses), CHUNK):
        out[s:s + CHUNK] = beam_log_likelihood(field, poses[s:s + CHUNK], sensor, angles, ranges,
                                               range_max, sigma)
    return out


def _beams(angles: np.ndarray, ranges: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    idx = np.flatnonzero(np.isfinite(ranges))
    if len(idx) > n:
        idx = idx[np.linspace(0, len(idx) - 1, n).astype(int)]
    return angles[idx], ranges[idx]


def global_poses(field: LikelihoodField, cells: np.ndarray, n: int, sensor: tuple[float, float, float],
                 angles: np.ndarray, ranges: np.ndarray, range_max: float,
                 rng: np.random.Generator) -> np.ndarray:
    """The ``n`` poses in ``cells`` that best explain the scan (valid returns only) → (n, 3)."""
    pos = _lattice(field, cells, rng)
    heads = np.linspace(-math.pi, math.pi, HEADINGS, endpoint=False)
    cand = np.repeat(pos, HEADINGS, axis=0)
    cand = np.column_stack([cand, wrap_angles(np.tile(heads, len(pos))
                                              + rng.uniform(0, 2 * math.pi / HEADINGS, len(cand)))])
    a, r = _beams(angles, ranges, COARSE_BEAMS)
    coarse = _score(field, cand, sensor, a, r, range_max, COARSE_SIGMA_M)
    keep = min(len(cand), max(REFINE_KEEP, n))
    best = cand[np.argpartition(coarse, -keep)[-keep:]]
    a, r = _beams(angles, ranges, REFINE_BEAMS)
    score = _score(field, best, sensor, a, r, range_max, SIGMA_HIT_M)
    for sxy, syaw in zip(REFINE_STEP_XY_M, REFINE_STEP_YAW_RAD, strict=True):
        trial = best + rng.normal(0.0, 1.0, best.shape) * np.array([sxy, sxy, syaw])
        trial[:, 2] = wrap_angles(trial[:, 2])
        s = _score(field, trial, sensor, a, r, range_max, SIGMA_HIT_M)
        better = s > score
        best[better], score[better] = trial[better], s[better]
    return best[np.argsort(score)[-n:]]


@dataclass(frozen=True)
class Hypothesis:
    """A place the filter still considers: weighted centre (x, y, m), share of the weight,
    and the weighted root-mean-square distance (m) of its particles from the centre."""

    x: float
    y: float
    share: float
    rms_m: float


def _clusters(particles: np.ndarray) -> tuple[np.ndarray, int]:
    """Cluster label per particle (0: none) and the number of clusters.

    Particles are binned on ``HYPOTHESIS_CELL_M`` squares; bins with at least
    ``HYPOTHESIS_CELL_MIN`` particles that touch (8-connected) form a place. Within a place,
    particles are split by heading into ``HEADING_SECTORS`` sectors; runs of occupied
    sectors (circular) form one cluster each. Two hypotheses that cross (a place and its
    point-symmetric twin pass through the centre of symmetry facing opposite ways) stay two."""
    xy = particles[:, :2]
    ij = np.floor((xy - xy.min(axis=0)) / HYPOTHESIS_CELL_M).astype(np.int64)
    rows, cols = int(ij[:, 1].max()) + 1, int(ij[:, 0].max()) + 1
    flat = ij[:, 1] * cols + ij[:, 0]
    counts = np.bincount(flat, minlength=rows * cols).reshape(rows, cols)
    labels, n = ndimage.label(counts >= HYPOTHESIS_CELL_MIN, structure=np.ones((3, 3), dtype=bool))
    place = labels.ravel()[flat]
    sector = np.floor((particles[:, 2] + math.pi) / (2 * math.pi / HEADING_SECTORS)).astype(np.int64)
    sector %= HEADING_SECTORS
    occupied = np.zeros((n + 1, HEADING_SECTORS), dtype=np.int64)
    np.add.at(occupied, (place, sector), 1)
    full = occupied >= HYPOTHESIS_CELL_MIN
    group = np.zeros((n + 1, HEADING_SECTORS), dtype=np.int64)
    k = 0
    for c in range(1, n + 1):
        row = full[c]
        if row.all():
            k += 1
            group[c] = k
            continue
        if not row.any():
            continue
        start = int(np.argmin(row))  # an empty sector: runs never wrap past it
        for j in range(1, HEADING_SECTORS + 1):
            s = (start + j) % HEADING_SECTORS
            if row[s]:
                if not row[(s - 1) % HEADING_SECTORS]:
                    k += 1
                group[c, s] = k
    return group[place, sector], k


def hypotheses(particles: np.ndarray, weights: np.ndarray,
               min_share: float = HYPOTHESIS_MIN_SHARE) -> list[Hypothesis]:
    """Clusters of the cloud (see :func:`_clusters`) holding at least ``min_share`` of the
    weight and ``HYPOTHESIS_MIN_PARTICLES`` particles, heaviest first."""
    lab, n = _clusters(particles)
    if n == 0:
        return []
    share = np.bincount(lab, weights=weights, minlength=n + 1)[1:] / max(float(weights.sum()), 1e-300)
    count = np.bincount(lab, minlength=n + 1)[1:]
    out = []
    for k in np.flatnonzero((share >= min_share) & (count >= HYPOTHESIS_MIN_PARTICLES)):
        sel = lab == k + 1
        w = weights[sel] + 1e-300
        c = np.average(particles[sel, :2], axis=0, weights=w)
        rms = math.sqrt(float(np.average(np.sum((particles[sel, :2] - c) ** 2, axis=1), weights=w)))
        out.append(Hypothesis(float(c[0]), float(c[1]), float(share[k]), rms))
    return sorted(out, key=lambda h: -h.share)


def keep_alive(particles: np.ndarray, weights: np.ndarray,
               loglik_per_beam: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Resampling probabilities ``q`` (sum 1) and per-particle weight factors ``boost``.

    ``q`` gives each of the ``KEEP_MAX`` strongest runner-up hypotheses at least
    ``KEEP_SHARE`` of the new particles (less when many are alive: together at most
    ``KEEP_BUDGET``) while it is alive. The caller weighs each drawn particle by
    ``weights · boost / q``, so a hypothesis keeps its weight: a look-alike place that fits
    a little worse for a while is not resampled away before the robot has seen what tells
    them apart. A runner-up is alive while its weight share is at least ``KEEP_MIN_WEIGHT``,
    or while its best particle explains the scan within ``AMBIGUOUS_LL_PER_BEAM`` (per beam,
    from ``loglik_per_beam``) of the leader's best: then ``boost`` lifts its share back to
    ``AMBIGUOUS_SHARE``. Tiny likelihood differences between two places that fit equally
    well (a map drawn a pixel off, a box that is not on the map) add up over a few updates;
    they must not decide between look-alike wings."""
    total = max(float(weights.sum()), 1e-300)
    ones = np.ones(len(weights))
    lab, n = _clusters(particles)
    if n <= 1:
        return weights / total, ones
    share = np.bincount(lab, weights=weights, minlength=n + 1) / total  # [0]: lone particles
    order = 1 + np.argsort(-share[1:])
    ambiguous = np.zeros(n + 1, dtype=bool)
    if loglik_per_beam is not None:
        best = np.full(n + 1, -np.inf)
        np.maximum.at(best, lab, loglik_per_beam)
        ambiguous = best >= best[order[0]] - AMBIGUOUS_LL_PER_BEAM
        ambiguous[0] = False
    runners = [c for c in order[1:KEEP_MAX + 1] if share[c] >= KEEP_MIN_WEIGHT or ambiguous[c]]
    post = share.copy()  # the weight share each cluster keeps
    for c in runners:
        post[c] = max(share[c], AMBIGUOUS_SHARE)
    post /= post.sum()
    # the share of particles each cluster gets: its weight share, topped up to the floor for
    # runner-ups; the top-ups (at most KEEP_BUDGET in all) come from everyone in proportion
    floor = min(KEEP_SHARE, KEEP_BUDGET / max(1, len(runners)))
    extra = np.zeros(n + 1)
    extra[runners] = np.maximum(floor - post[runners], 0.0)
    target = post * (1.0 - float(extra.sum())) + extra
    factor = np.divide(target, share, out=np.ones_like(share), where=share > 0)
    boost = np.divide(post, share, out=np.ones_like(share), where=share > 0)
    q = weights * factor[lab]
    return q / q.sum(), boost[lab]


def equal_share_weights(particles: np.ndarray) -> np.ndarray:
    """Weights (sum 1) that give every cluster of a fresh global cloud the same share, whatever
    the number of particles the search put there: a uniform prior over the look-alike
    places, not one that favours the place the search happened to sample densely. Lone
    particles keep an ordinary particle's weight."""
    n = len(particles)
    lab, k = _clusters(particles)
    if k == 0:
        return np.full(n, 1.0 / n)
    lone = lab == 0
    count = np.bincount(lab, minlength=k + 1)
    w = np.full(n, 1.0 / n)
    w[~lone] = (1.0 - lone.sum() / n) / k / count[lab[~lone]]
    weights: np.ndarray = w / w.sum()
    return weights
