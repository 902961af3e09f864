"""Tours planned for a visitor (brain/tours.py, brain/tour_routes.py): requests parsed, places
chosen by interest, route order, the time budget, path lengths on a hand-drawn map."""

from __future__ import annotations

import itertools
import json
import math

import pytest

from sage_robot.brain import tours
from sage_robot.brain.intents import classify
from sage_robot.brain.matching import content_words
from sage_robot.brain.tour_routes import RouteTable
from sage_robot.brain.tours import START, Candidate, candidates, interests_of, parse_budget_s, plan_tour
from sage_robot.core.mapio import read_map
from sage_robot.core.msgs import Pose2D, from_dict, to_dict
from sage_robot.core.msgs.tour import TourCommand, TourPhase, TourPlan, TourRequest, TourState, TourStop
from sage_robot.core.paths import package_data
from sage_robot.core.places import Place, Places, load_places

from ..support.grids import draw

SPEED_MPS = 0.5


def campus() -> Places:
    return load_places(package_data("maps", "campus", "waypoints.yaml"))


def line_places(xs: dict[str, float]) -> Places:
    return Places([Place(n, Pose2D(x, 0.0, 0.0), f"{n.lower()} lab") for n, x in xs.items()])


def line_distance(places: Places, start_x: float) -> tours.Distance:
    def distance(a: str, b: str) -> float:
        xa = start_x if a == START else places.get(a).pose.x
        return abs(places.get(b).pose.x - xa)

    return distance


@pytest.mark.parametrize(
    ("text", "seconds"),
    [
        ("I have ten minutes, show me the labs", 600.0),
        ("i only have 15 min", 900.0),
        ("we have half an hour", 1800.0),
        ("I have an hour", 3600.0),
        ("I have 2.5 minutes", 150.0),
        ("show me the labs", None),
    ],
)
def test_the_time_a_visitor_has(text: str, seconds: float | None) -> None:
    assert parse_budget_s(text) == seconds


def test_interests_are_split_and_stripped_of_time_and_filler() -> None:
    assert interests_of("I like robots and 3D printing") == ["robot", "3d print"]
    assert interests_of("I have ten minutes, show me the labs") == ["lab"]
    assert interests_of("I have ten minutes") == []


def test_interests_pick_the_places_that_answer_them() -> None:
    places = campus()
    kb = tours.kb_keywords(package_data("kb", "places"))
    picked = candidates(places, ["robot", "3d print"], kb)
    assert {c.place.name for c in picked} == {"VALPO_ROBOTICS", "3D_PRINTING_LAB"}
    assert {c.why for c in picked} == {"robot", "3d print"}
    labs = {c.place.name for c in candidates(places, ["lab"], kb)}
    assert {"BIO_ENG_LAB", "ECE_LAB_1", "CLEAN_ROOM"} - {"CLEAN_ROOM"} <= labs
    assert not labs & {"GUELLY_DELLY", "BATHROOMS", "DOCKING_STATION", "HESSE_CENTER"}
    everything = {c.place.name for c in candidates(places, [])}
    assert not everything & tours.NOT_ON_TOURS  # never the dock or the restrooms on a tour
    assert len(everything) == len(places) - len(tours.NOT_ON_TOURS)


def test_stops_come_in_route_order_from_the_robot() -> None:
    places = line_places({"A": 10.0, "B": 2.0, "C": 6.0, "D": 14.0})
    plan = plan_tour(candidates(places, []), line_distance(places, 0.0), SPEED_MPS)
    assert [s.name for s in plan.stops] == ["B", "C", "A", "D"]
    assert plan.drive_m == 14.0
    assert [s.leg_m for s in plan.stops] == [2.0, 4.0, 4.0, 4.0]
    assert plan.estimate_s == pytest.approx(14.0 / SPEED_MPS + 4 * tours.DWELL_S)


@pytest.mark.parametrize("n", [5, 9])
def test_route_order_is_no_longer_than_any_order_tried(n: int) -> None:
    """Exact up to EXACT_ORDER_MAX stops; nearest neighbour + 2-opt beyond it is checked
    against a sample of orders (and never longer than the order it started from)."""
    import numpy as np

    rng = np.random.default_rng(7)
    pts = {f"P{i}": (float(x), float(y)) for i, (x, y) in enumerate(rng.uniform(0, 50, size=(n, 2)))}

    def distance(a: str, b: str) -> float:
        pa = (0.0, 0.0) if a == START else pts[a]
        return math.dist(pa, pts[b])

    best = tours.route_length(tours.route_order(list(pts), distance), distance)
    orders = itertools.islice(itertools.permutations(pts), 2000)
    assert all(best <= tours.route_length(o, distance) + 1e-9 for o in orders)


def test_the_budget_is_respected_and_the_lowest_ranked_stops_go_first() -> None:
    places = line_places({"A": 10.0, "B": 20.0, "C": 30.0, "D": 40.0})
    ranked = [Candidate(places.get(n), s, "") for n, s in [("D", 3.0), ("A", 2.0), ("B", 1.0), ("C", 1.0)]]
    distance = line_distance(places, 0.0)
    for budget_s in (100.0, 150.0, 200.0, 300.0, 1000.0):
        plan = plan_tour(ranked, distance, SPEED_MPS, budget_s)
        if plan.ok:
            assert plan.estimate_s <= budget_s
            drive_s = tours.route_length([s.name for s in plan.stops], distance) / SPEED_MPS
            assert plan.estimate_s == pytest.approx(drive_s + len(plan.stops) * tours.DWELL_S)
    plan = plan_tour(ranked, distance, SPEED_MPS, 150.0)  # A and D: 80 s + 60 s; with B or C 170 s
    assert [s.name for s in plan.stops] == ["A", "D"]
    assert set(plan.dropped) == {"B", "C"}
    tight = plan_tour(ranked, distance, SPEED_MPS, 40.0)
    assert not tight.ok
    assert tight.reason == "even the nearest stop needs about 1 minute"  # A: 20 s + 30 s
    assert plan_tour([], distance, SPEED_MPS).reason == "no place fits the request"
    with pytest.raises(ValueError, match="cruise speed"):
        plan_tour(ranked, distance, 0.0)


def test_no_budget_keeps_at_most_max_stops_best_first() -> None:
    places = line_places({f"P{i}": float(i) for i in range(12)})
    plan = plan_tour(candidates(places, []), line_distance(places, 0.0), SPEED_MPS)
    assert len(plan.stops) == tours.MAX_STOPS
    assert [s.name for s in plan.stops] == [f"P{i}" for i in range(tours.MAX_STOPS)]
    assert plan.budget_s == 0.0


def test_path_lengths_on_a_map_go_around_walls() -> None:
    """Two rooms joined by a door at the top: B is 4 m from A as the crow flies, but the
    path goes up through the door and down again."""
    grid = draw(
        """
        ################
        #..............#
        #..............#
        #......#.......#
        #......#.......#
        #......#.......#
        #......#.......#
        ################
        """,
        resolution=0.5,
    )
    table = RouteTable(grid, {"A": (1.75, 1.25), "B": (5.75, 1.25)}, radius_m=0.2)
    straight = 4.0
    around = table.between("A", "B")
    assert straight + 1.0 < around < straight + 3.0  # up over the wall's end and down again
    assert table.between("A", "B") == pytest.approx(table.between("B", "A"))
    assert table.between("A", "A") == 0.0
    from_robot = table.from_point(1.75, 2.75)
    assert from_robot["A"] == pytest.approx(1.5, abs=0.3)
    assert from_robot["B"] > from_robot["A"]


def test_the_campus_labs_in_ten_minutes() -> None:
    """The issue's request on the default building, with path lengths on its map."""
    places = campus()
    table = RouteTable(read_map(package_data("maps", "campus", "map.yaml")),
                       {p.name: (p.pose.x, p.pose.y) for p in places}, radius_m=0.25)  # fmt: skip
    dock = places.get("DOCKING_STATION").pose
    first = table.from_point(dock.x, dock.y)

    def distance(a: str, b: str) -> float:
        return first[b] if a == START else table.between(a, b)

    text = "I have ten minutes, show me the labs"
    plan = plan_tour(candidates(places, interests_of(text)), distance, SPEED_MPS, parse_budget_s(text))
    assert plan.ok
    assert 2 <= len(plan.stops) <= tours.MAX_STOPS
    assert plan.estimate_s <= 600.0
    for stop in plan.stops:
        p = places.get(stop.name)
        assert "lab" in content_words(" ".join([p.name, *p.aliases, p.description])), p
    assert all(math.isfinite(s.leg_m) and s.leg_m > 0 for s in plan.stops)


@pytest.mark.parametrize(
    ("text", "intent", "slot"),
    [
        ("I have ten minutes, show me the labs", "tour", "lab"),
        ("I like robots and 3D printing", "tour", "robot and 3d print"),
        ("show me the cafe", "navigate", ""),
        ("pause the tour", "tour_control", "pause"),
        ("skip this one", "tour_control", "skip"),
        ("resume", "tour_control", "resume"),
        ("stop the tour", "tour_control", "stop"),
        ("stop", "cancel", ""),
    ],
)
def test_offline_intents_for_tours(text: str, intent: str, slot: str) -> None:
    got = classify(text, campus())
    assert got.name == intent
    assert got.slot == slot if intent != "navigate" else got.place_name == "GUELLY_DELLY"


@pytest.mark.parametrize(
    "msg",
    [
        TourRequest("labs", ("CLEAN_ROOM",), 600.0),
        TourPlan(
            True, (TourStop("CLEAN_ROOM", "Clean Room", 12.5, 25.0, "labs"),), 55.0, 12.5, 30.0, 600.0,
            ("ECE_LAB_2",), "map",
        ),
        TourCommand("start", ("A", "B"), 600.0, 300.0, "operator"),
        TourState(TourPhase.PAUSED, ("A", "B"), ("A", "B"), 1, ("A",), (), 300.0, 600.0, 12.0, "paused"),
    ],
    ids=lambda m: type(m).__name__,
)
def test_tour_messages_round_trip(msg: object) -> None:
    assert from_dict(json.loads(json.dumps(to_dict(msg)))) == msg
