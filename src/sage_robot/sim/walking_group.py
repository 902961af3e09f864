"""Walking groups: friends who walk together, side by side where the floor allows and one
behind the other where it does not (a narrow corridor, a doorway).

Pure (stdlib): a group is a leader (an ordinary walker who waits for the others when they
fall behind) and companions who keep a slot beside or behind it. Both crowd backends use
these rules (``sim/people.py``'s ``Crowd`` decides goals; JuPedSim or the simple walkers do
the walking). Map frame, metres, seconds.

Slots are given in the leader's frame (x ahead, y to its left). Pairs walk about 0.7 m
apart centre to centre (0.2 m between bodies): the spacing pedestrian studies report for
walking dyads (Moussaïd et al. 2010, "The walking behaviour of pedestrian social groups").
"""

from __future__ import annotations

import math
from collections.abc import Callable

ABREAST_M = 0.7  # centre-to-centre spacing of people walking side by side
FILE_M = 0.8  # spacing of people walking one behind the other
CATCH_UP_GAIN = 1.0  # extra speed (m/s) per metre a companion is behind its slot
COMPANION_MAX_MPS = 1.6  # a companion hurries at most this fast to catch up
COMPANION_MIN_MPS = 0.3  # ... and walks at least this fast toward its slot
LOOKAHEAD_S = 0.5  # a companion aims where its slot will be this much later
AT_SLOT_M = 0.2  # a companion this near its slot of a standing leader stands too
WAIT_FOR_M = 2.0  # the leader waits while a companion is this far from its slot
GROUP_WALK_MPS = (0.8, 1.05)  # groups walk slower than people alone (Moussaïd et al.)

Free = Callable[[float, float], bool]


def slots(size: int) -> list[tuple[tuple[float, float], tuple[float, float]]]:
    """For each companion of a group of ``size`` (leader included): its slot abreast and
    its slot in single file, (ahead, left) in the leader's frame."""
    abreast = [(0.0, ABREAST_M), (0.0, -ABREAST_M), (-FILE_M, 0.0)]
    in_file = [(-FILE_M * (k + 1), 0.0) for k in range(size - 1)]
    return [(abreast[k] if k < len(abreast) else in_file[k], in_file[k]) for k in range(size - 1)]


def slot_point(leader: tuple[float, float, float], slot: tuple[float, float]) -> tuple[float, float]:
    """A slot (ahead, left) of the leader at (x, y, heading), in the map frame."""
    c, s = math.cos(leader[2]), math.sin(leader[2])
    return (leader[0] + c * slot[0] - s * slot[1], leader[1] + s * slot[0] + c * slot[1])


def companion_goal(
    me: tuple[float, float],
    leader: tuple[float, float, float],
    leader_speed: float,
    slot: tuple[tuple[float, float], tuple[float, float]],
    free: Free,
) -> tuple[tuple[float, float], float] | None:
    """Where a companion at ``me`` heads for now and how fast, or None to stand (its leader
    stands and it is at its slot). The slot abreast when the floor there is free, else the
    one in single file."""
    abreast, in_file = slot
    target = slot_point(leader, abreast)
    if not free(*target):
        target = slot_point(leader, in_file)
    behind = math.hypot(target[0] - me[0], target[1] - me[1])
    if leader_speed < COMPANION_MIN_MPS / 2 and behind < AT_SLOT_M:
        return None
    ahead = leader_speed * LOOKAHEAD_S
    goal = (target[0] + ahead * math.cos(leader[2]), target[1] + ahead * math.sin(leader[2]))
    if not free(*goal):
        goal = target
    speed = min(COMPANION_MAX_MPS, max(COMPANION_MIN_MPS, leader_speed + CATCH_UP_GAIN * behind))
    return goal, speed


def lagging(me: tuple[float, float], leader: tuple[float, float, float],
            slot: tuple[tuple[float, float], tuple[float, float]]) -> bool:
    """True when a companion at ``me`` is WAIT_FOR_M from both its slots: the leader waits."""
    return all(math.hypot(q[0] - me[0], q[1] - me[1]) > WAIT_FOR_M
               for q in (slot_point(leader, slot[0]), slot_point(leader, slot[1])))
