"""Walking groups: friends who walk together, abreast in a wide corridor and in single file
in a narrow one, on both crowd backends; the default crowd has a pair; scenarios can ask
for companions. The world is stepped directly (simulated time, 10 ms steps)."""

from __future__ import annotations

import math

import pytest

from sage_robot.core.errors import ConfigError
from sage_robot.sim import walking_group as wg
from sage_robot.sim.lidar import LidarSpec
from sage_robot.sim.people import PersonState
from sage_robot.sim.spawn import people_from_specs, walking_party
from sage_robot.sim.world import World

from ..support.grids import room
from .test_people_jps import BACKENDS

DT_S = 0.01
TOGETHER_M = 1.5  # a companion this near its leader walks with it
MIDWAY_M = (6.0, 12.0)  # the stretch of the patrol (x) away from both of its ends


def _world(width_m: float, model: str, companions: int = 1,
           left_behind_m: float = 0.0) -> tuple[World, list[PersonState]]:
    """A 20 m corridor ``width_m`` wide; a party walks from its west end to its east end and
    back (its companions start ``left_behind_m`` further back than their slots); the robot
    parks at the far east end, out of their way."""
    grid = room(20.1, width_m + 0.1)
    mid = 0.05 + width_m / 2
    party = walking_party(0, (2.5 + left_behind_m, mid, 0.0), companions, 1.0)
    for c in party[1:]:
        c.x -= left_behind_m
    party[0].patrol, party[0].fixed = [(16.0, mid), (2.5, mid)], True
    quiet = LidarSpec(noise_fraction=0.0, noise_floor_m=0.0, dropout_probability=0.0)
    world = World(grid, (19.5, mid, math.pi), robot_radius=0.25, lidar=quiet, people=party,
                  people_model=model, seed=1)
    return world, party


def _walk(world: World, party: list[PersonState], seconds: float) -> tuple[list[float], list[float], float]:
    """Step ``seconds``; each step's distance from every companion to the leader, their
    offsets across the corridor mid-way (not where the patrol turns round and the pair swap
    ends), and how far the leader walked."""
    gaps, across, walked = [], [], 0.0
    last = (party[0].x, party[0].y)
    for _ in range(round(seconds / DT_S)):
        world.step(DT_S)
        lead = party[0]
        walked += math.hypot(lead.x - last[0], lead.y - last[1])
        last = (lead.x, lead.y)
        for c in party[1:]:
            gaps.append(math.hypot(c.x - lead.x, c.y - lead.y))
            if lead.moving > 0.3 and MIDWAY_M[0] < lead.x < MIDWAY_M[1]:
                across.append(abs(c.y - lead.y))
    return gaps, across, walked


@pytest.mark.parametrize("model", BACKENDS)
def test_a_pair_walks_abreast_in_a_wide_corridor(model: str) -> None:
    world, party = _world(3.0, model)
    gaps, across, walked = _walk(world, party, 40.0)
    assert walked > 20.0, f"the leader walked only {walked:.1f} m in 40 s"
    together = sum(g <= TOGETHER_M for g in gaps) / len(gaps)
    assert together >= 0.9, f"the pair was together {together:.0%} of the time"
    side_by_side = sum(a >= wg.ABREAST_M / 2 for a in across) / len(across)
    assert side_by_side >= 0.7, f"abreast only {side_by_side:.0%} of the walk in a 3 m corridor"


@pytest.mark.parametrize("model", BACKENDS)
def test_a_pair_walks_in_single_file_in_a_narrow_corridor(model: str) -> None:
    world, party = _world(1.1, model)  # two bodies abreast need 1.2 m with the walls' margin
    gaps, across, walked = _walk(world, party, 40.0)
    assert walked > 20.0, f"the leader walked only {walked:.1f} m in 40 s"
    assert sum(g <= TOGETHER_M for g in gaps) / len(gaps) >= 0.9
    assert max(across) < 0.45, f"a companion was {max(across):.2f} m beside its leader in 1.1 m"


@pytest.mark.parametrize("model", BACKENDS)
def test_a_leader_waits_for_a_companion_left_behind(model: str) -> None:
    world, party = _world(3.0, model, left_behind_m=6.0)
    first = (party[0].x, party[0].y)
    _walk(world, party, 1.0)  # the companion hurries on; the leader waits while it is 2 m back
    assert math.hypot(party[0].x - first[0], party[0].y - first[1]) < 0.05, "the leader left it behind"
    gaps, _, walked = _walk(world, party, 20.0)
    assert walked > 8.0
    assert gaps[-1] <= TOGETHER_M


def test_slots_and_goals() -> None:
    assert wg.slots(2) == [((0.0, wg.ABREAST_M), (-wg.FILE_M, 0.0))]
    assert [s[1] for s in wg.slots(4)] == [(-wg.FILE_M, 0.0), (-2 * wg.FILE_M, 0.0), (-3 * wg.FILE_M, 0.0)]
    x, y = wg.slot_point((1.0, 2.0, math.pi / 2), (0.0, 0.7))  # left of a leader facing +y
    assert (x, y) == pytest.approx((0.3, 2.0))
    slot = wg.slots(2)[0]
    # free everywhere: the slot abreast, aimed a little ahead, faster while behind
    found = wg.companion_goal((0.0, 0.0), (0.0, 0.0, 0.0), 1.0, slot, lambda x, y: True)
    assert found is not None
    goal, speed = found
    assert goal == pytest.approx((wg.LOOKAHEAD_S, wg.ABREAST_M))
    assert speed > 1.0
    # the floor beside the leader is a wall: single file behind it
    found = wg.companion_goal((0.0, 0.0), (0.0, 0.0, 0.0), 0.0, slot, lambda x, y: abs(y) < 0.3)
    assert found is not None
    assert found[0] == pytest.approx((-wg.FILE_M, 0.0))
    # a standing leader, the companion at its slot: it stands too
    assert wg.companion_goal((0.0, 0.7), (0.0, 0.0, 0.0), 0.0, slot, lambda x, y: True) is None
    assert wg.lagging((-3.0, 0.0), (0.0, 0.0, 0.0), slot)
    assert not wg.lagging((-1.0, 0.0), (0.0, 0.0, 0.0), slot)


def test_the_default_crowd_has_a_pair_walking_together() -> None:
    from sage_robot.core.config import Settings
    from sage_robot.sim.setup import build_world

    world = build_world(Settings.model_validate({"sim": {"pedestrians": 10, "seed": 4}}), None)
    companions = [p for p in world.crowd.people if p.behaviour == "companion"]
    assert len(companions) == 1
    leader = next(p for p in world.crowd.people if p.id == companions[0].leader)
    assert leader.behaviour == "walker"
    assert leader is not companions[0]
    assert math.hypot(leader.x - companions[0].x, leader.y - companions[0].y) <= TOGETHER_M


def test_scenario_walkers_take_companions() -> None:
    def resolve(value, where):
        return (float(value[0]), float(value[1]), 0.0)

    people = people_from_specs([{"kind": "stander", "at": [1, 1]},
                                {"kind": "walker", "at": [5, 1], "to": [9, 1], "companions": 2}], 0, resolve)
    assert [(p.id, p.behaviour, p.leader) for p in people] == [
        (0, "stander", -1), (1, "walker", -1), (2, "companion", 1), (3, "companion", 1)]
    for bad, says in (({"kind": "walker", "at": [0, 0], "companions": 9}, "from 0 to 3"),
                      ({"kind": "walker", "at": [0, 0], "companions": "two"}, "whole number"),
                      ({"kind": "stander", "at": [0, 0], "companions": 1}, "only a walker")):
        with pytest.raises(ConfigError, match=says):
            people_from_specs([bad], 0, resolve)
