"""The default building: a generated first floor modelled on the seed's (Gellersen, 1st floor).

Two long corridors cross near the middle (east–west 98 m × 3.0 m, north–south 78 m ×
2.2 m) and a narrower east wing (1.8 m) branches off; labs, a café, restrooms, offices
and a docking alcove open off them through 1.8 m doorways. Every one of the seed's 16
places is a waypoint with a description and spoken aliases.

Everything is plain data below and :func:`generate` is deterministic:
``scripts/generate_building.py`` rewrites ``data/maps/campus/`` byte for byte.

Map frame: x east, y north (m), origin at the map's lower-left corner; 0.05 m cells,
2000 × 1600. Outside the building is unknown, walls are occupied, floors are free.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from sage_robot.core.mapio import FREE, OCCUPIED, UNKNOWN, write_map
from sage_robot.core.msgs import OccupancyGrid, Pose2D
from sage_robot.core.places import Place, Places, write_places

RESOLUTION_M = 0.05
SIZE_M = (100.0, 80.0)  # map width (x) and height (y)
WALL_M = 0.2
DOOR_M = 1.8  # double doors: the centre is 0.9 m from each jamb
PLACE_DEPTH_M = 3.0  # a place stands this far inside its room from the door
EW_Y = (38.5, 41.5)  # east-west corridor, 3.0 m
NS_X = (48.9, 51.1)  # north-south corridor, 2.2 m
WING_Y = (62.0, 63.8)  # east wing corridor, 1.8 m
WING_X_END = 80.0
CORRIDOR_END_M = 1.0  # corridors stop this far from the map edge

N, S, E, W = "N", "S", "E", "W"  # which wall of a room holds its door (the corridor side)


@dataclass(frozen=True)
class Room:
    """A rectangular room (interior, m) with one door of ``door_m`` in its ``side`` wall."""

    label: str
    x0: float
    y0: float
    x1: float
    y1: float
    side: str
    place: str = ""
    door_m: float = DOOR_M
    door_at: float | None = None  # door centre along the wall; None = the wall's middle
    islands: tuple[tuple[float, float, float, float], ...] = ()  # benches/counters (x0,y0,x1,y1)

    def door_centre(self) -> tuple[float, float]:
        if self.side in (N, S):
            x = self.door_at if self.door_at is not None else (self.x0 + self.x1) / 2
            return (x, self.y1 + WALL_M / 2 if self.side == N else self.y0 - WALL_M / 2)
        y = self.door_at if self.door_at is not None else (self.y0 + self.y1) / 2
        return (self.x1 + WALL_M / 2 if self.side == E else self.x0 - WALL_M / 2, y)

    def inward(self) -> tuple[float, float]:
        """Unit vector from the door into the room."""
        return {N: (0.0, -1.0), S: (0.0, 1.0), E: (-1.0, 0.0), W: (1.0, 0.0)}[self.side]


NORTH_ROW = (EW_Y[1] + WALL_M, EW_Y[1] + WALL_M + 8.0)  # rooms north of the E-W corridor
SOUTH_ROW = (EW_Y[0] - WALL_M - 8.0, EW_Y[0] - WALL_M)


def _ew_room(label: str, x0: float, x1: float, north: bool, place: str = "", **kw: Any) -> Room:
    y0, y1 = NORTH_ROW if north else SOUTH_ROW
    return Room(label, x0, y0, x1, y1, S if north else N, place, **kw)


ROOMS: tuple[Room, ...] = (
    # North of the east-west corridor, west to east.
    _ew_room("Bioengineering lab", 1.0, 11.0, True, "BIO_ENG_LAB"),
    _ew_room("Senior design", 11.2, 25.0, True, "SENIOR_DESIGN", islands=((14.0, 46.5, 22.0, 47.5),)),
    _ew_room(
        "Guelly Delly café",
        25.2,
        37.0,
        True,
        "GUELLY_DELLY",
        door_m=3.0,
        islands=((27.0, 47.0, 27.8, 47.8), (29.5, 47.0, 30.3, 47.8), (32.0, 47.0, 32.8, 47.8)),
    ),
    _ew_room("Restrooms", 37.2, 42.0, True, "BATHROOMS"),
    _ew_room("Faculty offices", 42.2, 48.7, True),
    _ew_room("Mechatronics lab", 51.3, 60.0, True, "MECHATRONICS_LAB"),
    _ew_room("Valpo Robotics", 60.2, 72.0, True, "VALPO_ROBOTICS"),
    _ew_room("ECE lab 1", 72.2, 86.0, True, "ECE_LAB_1", islands=((75.0, 47.0, 83.0, 48.0),)),
    _ew_room("ECE lab 2", 86.2, 99.0, True, "ECE_LAB_2", islands=((89.0, 47.0, 96.0, 48.0),)),
    # South of the east-west corridor.
    _ew_room("Manufacturing lab", 1.0, 14.0, False, "MANUFACTURING_LAB", islands=((4.0, 31.5, 11.0, 32.5),)),
    _ew_room("3D printing lab", 14.2, 24.0, False, "3D_PRINTING_LAB", islands=((16.0, 31.4, 22.0, 32.2),)),
    _ew_room("Clean room", 24.2, 34.0, False, "CLEAN_ROOM"),
    _ew_room("Storage", 34.2, 42.0, False),
    _ew_room("Offices", 42.2, 48.7, False),
    _ew_room("Materials testing lab", 51.3, 64.0, False, "MATERIALS_TESTING_LAB"),
    _ew_room("Heat power lab", 64.2, 78.0, False, "HEAT_POWER_LAB"),
    _ew_room("Transportation lab", 78.2, 99.0, False, "TRANSPORTATION_LAB"),
    # West of the north-south corridor.
    Room("Faculty offices north", 40.7, 49.9, 48.7, 56.0, E),
    Room("Study lounge", 40.7, 59.0, 48.7, 79.0, E),
    Room("Machine shop", 40.7, 1.0, 48.7, 15.0, E),
    Room("Fluids lab", 40.7, 15.2, 48.7, 30.1, E),
    # East of the north-south corridor.
    Room("Conference room", 51.3, 49.9, 59.3, 61.8, W),
    Room("Lecture hall", 51.3, 64.0, 59.3, 79.0, W),
    Room("Lecture hall south", 51.3, 1.0, 59.3, 15.0, W),
    Room("Design studio", 51.3, 15.2, 59.3, 30.1, W),
    # Along the east wing.
    Room("Hesse Center", 59.5, 64.0, 72.0, 72.0, S, "HESSE_CENTER"),
    Room("Computer lab", 72.2, 64.0, WING_X_END, 72.0, S),
    Room("Graduate offices", 59.5, 49.9, 70.0, 61.8, N),
    Room("Electronics shop", 70.2, 49.9, WING_X_END, 61.8, N),
)

# The docking alcove: a recess in the N-S corridor's west wall; the robot docks facing east.
DOCK_ALCOVE = (46.3, 56.2, NS_X[0], 58.8)
DOCK_POSE = (47.3, 57.5, 0.0)

CORRIDORS: tuple[tuple[float, float, float, float], ...] = (
    (CORRIDOR_END_M, EW_Y[0], SIZE_M[0] - CORRIDOR_END_M, EW_Y[1]),
    (NS_X[0], CORRIDOR_END_M, NS_X[1], SIZE_M[1] - CORRIDOR_END_M),
    (NS_X[1], WING_Y[0], WING_X_END, WING_Y[1]),
)

PLACE_INFO: dict[str, tuple[str, tuple[str, ...], str]] = {
    # name: (description for the LLM, spoken aliases, dwell text)
    "BIO_ENG_LAB": (
        "Bioengineering student project space",
        ("bio lab", "bioengineering lab", "bio engineering lab"),
        "This is the bioengineering project space, where students build medical devices.",
    ),
    "SENIOR_DESIGN": (
        "Senior design collaboration space",
        ("senior design", "senior design lab", "capstone lab"),
        "This is the senior design space, where seniors work on their capstone projects.",
    ),
    "GUELLY_DELLY": (
        "Engineering student café (breakfast/lunch)",
        ("the cafe", "Guelly Delly", "the deli", "the café", "coffee shop", "cafeteria"),
        "Here is the Guelly Delly, the engineering café for breakfast and lunch.",
    ),
    "MANUFACTURING_LAB": (
        "Manufacturing and fabrication lab",
        ("manufacturing lab", "manufacturing", "machining lab"),
        "This is the manufacturing lab, with machines for fabrication.",
    ),
    "3D_PRINTING_LAB": (
        "3D printing and fabrication lab",
        ("3D printing lab", "three d printing", "3D printers", "printing lab"),
        "This is the 3D printing lab, full of printers for student projects.",
    ),
    "CLEAN_ROOM": (
        "Controlled environment for sensitive fabrication",
        ("clean room", "cleanroom"),
        "This is the clean room, a controlled environment for sensitive fabrication.",
    ),
    "ECE_LAB_1": (
        "ECE lab with workbenches and tools",
        ("ECE lab one", "first ECE lab", "electrical engineering lab"),
        "This is the first ECE lab, with workbenches and instruments.",
    ),
    "ECE_LAB_2": ("Second ECE lab", ("ECE lab two", "second ECE lab"), "This is the second ECE lab."),
    "MECHATRONICS_LAB": (
        "Mechatronics projects and research",
        ("mechatronics", "mechatronics lab"),
        "This is the mechatronics lab, for projects and research.",
    ),
    "VALPO_ROBOTICS": (
        "Valpo Robotics student space",
        ("Valpo Robotics", "robotics lab", "robotics club"),
        "This is the Valpo Robotics student space.",
    ),
    "HESSE_CENTER": (
        "Tutoring and study center",
        ("Hesse Center", "tutoring center", "study center", "tutoring"),
        "This is the Hesse Center, for tutoring and study.",
    ),
    "BATHROOMS": (
        "Nearest restroom facilities",
        ("bathroom", "restroom", "restrooms", "toilets", "washroom"),
        "The restrooms are right here.",
    ),
    "MATERIALS_TESTING_LAB": (
        "Materials science testing space",
        ("materials lab", "materials testing", "materials testing lab"),
        "This is the materials testing lab.",
    ),
    "HEAT_POWER_LAB": (
        "Thermodynamics and heat transfer lab",
        ("heat power lab", "heat and power lab", "thermodynamics lab", "thermo lab"),
        "This is the heat power lab, for thermodynamics and heat transfer.",
    ),
    "TRANSPORTATION_LAB": (
        "Transportation engineering projects",
        ("transportation lab", "transportation", "traffic lab"),
        "This is the transportation lab.",
    ),
    "DOCKING_STATION": (
        "Robot charging/docking location",
        ("docking station", "dock", "charger", "charging station", "home base"),
        "This is my docking station, where I charge.",
    ),
}

# Low obstacles under the lidar's scan plane: part of the world, not of the map. Placed
# off every default route (dead ends, room corners); scenarios add more where they want.
CLUTTER: tuple[dict[str, Any], ...] = (
    {
        "name": "corridor_bench_west",
        "kind": "bench",
        "center": [2.2, 41.2],
        "size": [1.6, 0.45],
        "yaw": 0.0,
        "height": 0.45,
    },
    {
        "name": "corridor_cart_east",
        "kind": "cart",
        "center": [98.0, 39.1],
        "size": [0.9, 0.6],
        "yaw": 0.3,
        "height": 0.40,
    },
    {
        "name": "cafe_bench",
        "kind": "bench",
        "center": [35.6, 49.2],
        "size": [1.6, 0.45],
        "yaw": 0.0,
        "height": 0.45,
    },
    {
        "name": "manufacturing_cart",
        "kind": "cart",
        "center": [1.8, 37.4],
        "size": [0.9, 0.6],
        "yaw": 0.0,
        "height": 0.40,
    },
)


# ---------------------------------------------------------------- rasterizing


def _cells(v: float) -> int:
    return round(v / RESOLUTION_M)


def _paint(data: np.ndarray, rect: tuple[float, float, float, float], value: int, grow: float = 0.0) -> None:
    x0, y0, x1, y1 = rect
    r0, r1 = _cells(y0 - grow), _cells(y1 + grow)
    c0, c1 = _cells(x0 - grow), _cells(x1 + grow)
    data[max(r0, 0) : max(r1, 0), max(c0, 0) : max(c1, 0)] = value


def _door_rect(room: Room) -> tuple[float, float, float, float]:
    x, y = room.door_centre()
    h = room.door_m / 2
    t = WALL_M / 2 + RESOLUTION_M  # a little past the wall on both sides
    return (x - h, y - t, x + h, y + t) if room.side in (N, S) else (x - t, y - h, x + t, y + h)


def build_grid() -> OccupancyGrid:
    """The occupancy grid (row 0 at y = 0) of the default building."""
    w, h = _cells(SIZE_M[0]), _cells(SIZE_M[1])
    data = np.full((h, w), UNKNOWN, dtype=np.int8)
    spaces = [(r.x0, r.y0, r.x1, r.y1) for r in ROOMS] + list(CORRIDORS) + [DOCK_ALCOVE]
    for rect in spaces:
        _paint(data, rect, OCCUPIED, grow=WALL_M)
    for rect in spaces:
        _paint(data, rect, FREE)
    for room in ROOMS:
        _paint(data, _door_rect(room), FREE)
        for island in room.islands:
            _paint(data, island, OCCUPIED)
    # The alcove opens into the corridor along its whole width.
    _paint(data, (DOCK_ALCOVE[0], DOCK_ALCOVE[1], NS_X[0] + RESOLUTION_M, DOCK_ALCOVE[3]), FREE)
    return OccupancyGrid(0.0, "map", RESOLUTION_M, Pose2D(0.0, 0.0, 0.0), data)


def build_places() -> Places:
    """The 16 places: each stands PLACE_DEPTH_M inside its room, facing in from the door."""
    places = []
    for room in ROOMS:
        if not room.place:
            continue
        dx, dy = room.door_centre()
        ux, uy = room.inward()
        pose = Pose2D(
            round(dx + ux * PLACE_DEPTH_M, 3), round(dy + uy * PLACE_DEPTH_M, 3), round(math.atan2(uy, ux), 4)
        )
        places.append(_place(room.place, pose))
    places.append(_place("DOCKING_STATION", Pose2D(*DOCK_POSE)))
    order = list(PLACE_INFO)
    places.sort(key=lambda p: order.index(p.name))
    return Places(places, "default building")


def _place(name: str, pose: Pose2D) -> Place:
    description, aliases, dwell = PLACE_INFO[name]
    return Place(name, pose, description, aliases, dwell)


# ---------------------------------------------------------------- walking lanes


def _corridor_of(room: Room) -> int:
    """Which corridor a room's door opens on: 0 east-west, 1 north-south, 2 the east wing."""
    _, dy = room.door_centre()
    if room.side in (E, W):
        return 1
    on_ew = abs(dy - (EW_Y[0] - WALL_M / 2)) < WALL_M or abs(dy - (EW_Y[1] + WALL_M / 2)) < WALL_M
    return 0 if on_ew else 2


def build_lanes() -> dict[str, Any]:
    """A graph of where people walk: corridor centre lines (split at junctions and doors)
    and a spur from each door into its room. Edges carry the lateral half-width (m)
    a walker may stray from the line."""
    nodes: list[tuple[float, float]] = []

    def node(x: float, y: float) -> int:
        p = (round(x, 3), round(y, 3))
        if p not in nodes:
            nodes.append(p)
        return nodes.index(p)

    edges: list[tuple[int, int, float]] = []
    ew_y, ns_x, wing_y = sum(EW_Y) / 2, sum(NS_X) / 2, sum(WING_Y) / 2
    lines = [  # (fixed coordinate, axis, start, end, half width)
        (ew_y, "x", CORRIDOR_END_M + 1.0, SIZE_M[0] - CORRIDOR_END_M - 1.0, (EW_Y[1] - EW_Y[0]) / 2),
        (ns_x, "y", CORRIDOR_END_M + 1.0, SIZE_M[1] - CORRIDOR_END_M - 1.0, (NS_X[1] - NS_X[0]) / 2),
        (wing_y, "x", ns_x, WING_X_END - 1.0, (WING_Y[1] - WING_Y[0]) / 2),
    ]
    stops: list[list[float]] = [[a, b] for _, _, a, b, _ in lines]
    stops[0].append(ns_x)
    stops[1] += [ew_y, wing_y]
    spur_rooms = [r for r in ROOMS if r.place]
    for room in spur_rooms:
        dx, dy = room.door_centre()
        line = _corridor_of(room)
        stops[line].append(dx if lines[line][1] == "x" else dy)
    for (fixed, axis, _, _, half), pts in zip(lines, stops, strict=True):
        ids = [node(v, fixed) if axis == "x" else node(fixed, v) for v in sorted(set(pts))]
        edges += [(a, b, half) for a, b in itertools.pairwise(ids)]
    for room in spur_rooms:
        dx, dy = room.door_centre()
        ux, uy = room.inward()
        line_pt = [(dx, ew_y), (ns_x, dy), (dx, wing_y)][_corridor_of(room)]
        inside = node(dx + ux * PLACE_DEPTH_M, dy + uy * PLACE_DEPTH_M)
        edges.append((node(*line_pt), inside, 0.4))
    return {"nodes": [list(p) for p in nodes], "edges": [[a, b, round(h, 3)] for a, b, h in edges]}


# ---------------------------------------------------------------- files


def generate(out_dir: str | Path) -> list[Path]:
    """Write map.yaml + map.pgm, waypoints.yaml and world.yaml into ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = [write_map(build_grid(), out / "map.yaml")]
    written.append(out / "map.pgm")
    write_places(build_places(), out / "waypoints.yaml")
    written.append(out / "waypoints.yaml")
    world = {
        "description": "The default building's world beyond the map: low obstacles (under the "
        "lidar's scan plane) and the lanes simulated people walk along. Generated by "
        "scripts/generate_building.py; do not edit by hand.",
        "low_obstacles": [dict(c) for c in CLUTTER],
        "lanes": build_lanes(),
    }
    (out / "world.yaml").write_text(yaml.safe_dump(world, sort_keys=False, width=100), encoding="utf-8")
    written.append(out / "world.yaml")
    return written
