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

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sage_robot.core.geometry import wrap_angles
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


def relation_indices(
    stamps: np.ndarray, relations: list[Relation], tolerance_s: float = MATCH_TOLERANCE_S
) -> tuple[np.ndarray, np.ndarray]:
    """Indices into the sorted ``stamps`` of each relation's first and second pose."""
    stamps = np.asarray(stamps, dtype=np.float64)
    i = match_stamps(stamps, np.array([r.t1 for r in relations]), tolerance_s)
    j = match_stamps(stamps, np.array([r.t2 for r in relations]), tolerance_s)
    return i, j


def relative_poses(poses: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """(N, 3) relative poses ⊖x_i ⊕ x_j of ``poses`` (x, y m; θ rad): (dx, dy) in x_i's frame."""
    poses = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    a, b = poses[i], poses[j]
    c, s = np.cos(a[:, 2]), np.sin(a[:, 2])
    d = b[:, :2] - a[:, :2]
    return np.column_stack(
        (c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], wrap_angles(b[:, 2] - a[:, 2]))
    )


def reference_array(relations: list[Relation]) -> np.ndarray:
    """(N, 3) reference relative poses (dx, dy m; dθ rad)."""
    return np.array([(r.dx, r.dy, r.dtheta) for r in relations], dtype=np.float64).reshape(-1, 3)


def error_parts(reference: np.ndarray, estimate: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per relation |ε_xy| (m) and |ε_θ| (rad) of ε = ⊖δ* ⊕ δ; both (N, 3) relative poses."""
    reference = np.asarray(reference, dtype=np.float64).reshape(-1, 3)
    estimate = np.asarray(estimate, dtype=np.float64).reshape(-1, 3)
    # ⊖δ* ⊕ δ: the translation difference turned into δ*'s frame keeps its length
    trans = np.hypot(estimate[:, 0] - reference[:, 0], estimate[:, 1] - reference[:, 1])
    rot = np.abs(wrap_angles(estimate[:, 2] - reference[:, 2]))
    return trans, rot


def summarize(trans: np.ndarray, rot: np.ndarray) -> RelationError:
    """Mean ± std of per-relation errors (m, rad) as a :class:`RelationError` (rotation in deg)."""
    if len(trans) == 0:
        return RelationError(0, 0.0, 0.0, 0.0, 0.0, 0.0)
    rot_deg = np.degrees(rot)
    return RelationError(
        len(trans),
        float(trans.mean()),
        float(trans.std()),
        float(rot_deg.mean()),
        float(rot_deg.std()),
        float(trans.max()),
        float(np.median(trans)),
    )


def relation_error(
    stamps: np.ndarray, poses: np.ndarray, relations: list[Relation], tolerance_s: float = MATCH_TOLERANCE_S
) -> RelationError:
    """Mean ± std of the translational (m) and rotational (deg) relation errors.

    ``stamps`` (sorted, s) and ``poses`` (N, 3: x, y m; theta rad) are the estimated trajectory.
    """
    i, j = relation_indices(stamps, relations, tolerance_s)
    return summarize(*error_parts(reference_array(relations), relative_poses(poses, i, j)))
