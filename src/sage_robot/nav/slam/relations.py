"""The relation-based SLAM error of Kümmerle et al. 2009 ("On measuring the accuracy of SLAM
algorithms", Autonomous Robots 27(4)).

A relation file has one line per relation: ``t1 t2 x y z roll pitch yaw`` — the reference
relative pose (m, rad) from the robot's pose at time ``t1`` to its pose at ``t2``. For each
relation the estimated relative pose δ = ⊖x(t1) ⊕ x(t2) is compared with the reference δ*:
the error is ε = ⊖δ* ⊕ δ; its translational part is |(ε_x, ε_y)| (m) and its rotational part
|ε_θ| (reported in degrees). The result is the mean and standard deviation of both over all
relations. Timestamps are matched to the nearest scan timestamp.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sage_robot.core.geometry import relative
from sage_robot.nav.slam.carmen import LogFormatError, open_text

RELATION_FIELDS = 8  # t1 t2 x y z roll pitch yaw
MATCH_TOLERANCE_S = 0.01  # a relation timestamp this far from every scan is an error


@dataclass(frozen=True)
class Relation:
    t1: float  # s
    t2: float  # s
    dx: float  # m, in the frame of the pose at t1
    dy: float  # m
    dtheta: float  # rad


@dataclass(frozen=True)
class RelationError:
    count: int
    trans_mean_m: float
    trans_std_m: float
    rot_mean_deg: float
    rot_std_deg: float
    trans_max_m: float
    trans_median_m: float = 0.0

    def as_dict(self) -> dict[str, float | int]:
        return {
            "relations": self.count,
            "trans_error_mean_m": round(self.trans_mean_m, 5),
            "trans_error_std_m": round(self.trans_std_m, 5),
            "trans_error_median_m": round(self.trans_median_m, 5),
            "trans_error_max_m": round(self.trans_max_m, 4),
            "rot_error_mean_deg": round(self.rot_mean_deg, 4),
            "rot_error_std_deg": round(self.rot_std_deg, 4),
        }


def read_relations(path: str | Path) -> list[Relation]:
    """Parse a relations file; a malformed line raises naming ``file:line``."""
    path = Path(path)
    out: list[Relation] = []
    for number, text in enumerate(open_text(path), start=1):
        fields = text.split()
        if not fields or fields[0].startswith("#"):
            continue
        if len(fields) != RELATION_FIELDS:
            raise LogFormatError(
                f"{path}:{number}: expected 8 numbers 't1 t2 x y z roll pitch yaw', "
                f"found {len(fields)} fields"
            )
        try:
            v = [float(f) for f in fields]
        except ValueError:
            raise LogFormatError(f"{path}:{number}: expected 8 numbers, got {text.strip()!r}") from None
        out.append(Relation(v[0], v[1], v[2], v[3], v[7]))
    if not out:
        raise LogFormatError(f"{path}: no relations in the file")
    return out


def match_stamps(stamps: np.ndarray, query: np.ndarray, tolerance_s: float = MATCH_TOLERANCE_S) -> np.ndarray:
    """Index of the nearest of the sorted ``stamps`` for each ``query`` time."""
    idx = np.clip(np.searchsorted(stamps, query), 1, len(stamps) - 1)
    left, right = stamps[idx - 1], stamps[idx]
    idx = np.where(np.abs(query - left) <= np.abs(right - query), idx - 1, idx)
    gap = np.abs(stamps[idx] - query)
    if len(gap) and gap.max() > tolerance_s:
        worst = int(np.argmax(gap))
        raise LogFormatError(
            f"relation timestamp {query[worst]:.6f} is {gap[worst]:.3f} s from the nearest scan: "
            "do the relations belong to this log?"
        )
    return idx


def relation_error(
    stamps: np.ndarray, poses: np.ndarray, relations: list[Relation], tolerance_s: float = MATCH_TOLERANCE_S
) -> RelationError:
    """Mean ± std of the translational (m) and rotational (deg) relation errors.

    ``stamps`` (sorted, s) and ``poses`` (N, 3: x, y m; theta rad) are the estimated trajectory.
    """
    stamps = np.asarray(stamps, dtype=np.float64)
    i = match_stamps(stamps, np.array([r.t1 for r in relations]), tolerance_s)
    j = match_stamps(stamps, np.array([r.t2 for r in relations]), tolerance_s)
    trans = np.empty(len(relations))
    rot = np.empty(len(relations))
    for k, rel in enumerate(relations):
        est = relative(tuple(poses[i[k]]), tuple(poses[j[k]]))
        err = relative((rel.dx, rel.dy, rel.dtheta), est)
        trans[k] = math.hypot(err[0], err[1])
        rot[k] = abs(err[2])
    rot_deg = np.degrees(rot)
    return RelationError(
        len(relations),
        float(trans.mean()),
        float(trans.std()),
        float(rot_deg.mean()),
        float(rot_deg.std()),
        float(trans.max()),
        float(np.median(trans)),
    )
