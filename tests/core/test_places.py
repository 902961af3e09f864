import math

import numpy as np
import pytest

from sage_robot.core.errors import ConfigError
from sage_robot.core.places import load_places, parse_places, validate_places, write_places

from ..support.grids import grid_of

SEED_STYLE = """
BIO_ENG_LAB:
  pose:
    position: {x: 1.0, y: 2.0, z: 0.0}
    orientation: {x: 0.0, y: 0.0, z: 0.7071068, w: 0.7071068}
GUELLY_DELLY:
  pose:
    position: {x: 3.0, y: 4.0, z: 0.0}
    orientation: {x: 0.0, y: 0.0, z: 0.0, w: 1.0}
"""

OWN = {
    "places": [
        {
            "name": "GUELLY_DELLY",
            "pose": [3, 4, 0],
            "description": "Engineering student café",
            "aliases": ["the cafe", "guelly delly", "the deli"],
        },
        {"name": "3D_PRINTING_LAB", "pose": [5, 1, 1.0], "description": "3D printing"},
    ]
}


def test_seed_nav2_style_loads(tmp_path):
    f = tmp_path / "new_waypoints.yaml"
    f.write_text(SEED_STYLE)
    places = load_places(f)
    assert places.names() == ["BIO_ENG_LAB", "GUELLY_DELLY"]
    assert places.get("BIO_ENG_LAB").pose.theta == pytest.approx(math.pi / 2, abs=1e-6)


def test_own_format_round_trip(tmp_path):
    places = parse_places(OWN, "w.yaml")
    write_places(places, tmp_path / "w.yaml")
    again = load_places(tmp_path / "w.yaml")
    assert [(p.name, p.aliases) for p in again] == [(p.name, p.aliases) for p in places]


@pytest.mark.parametrize(
    ("spoken", "expected"),
    [
        ("the cafe", "GUELLY_DELLY"),
        ("Guelly Deli", "GUELLY_DELLY"),
        ("three d printing lab", "3D_PRINTING_LAB"),
        ("3D_PRINTING_LAB", "3D_PRINTING_LAB"),
        ("the moon", None),
    ],
)
def test_resolve_names_aliases_and_stt_errors(spoken, expected):
    found = parse_places(OWN, "w.yaml").resolve(spoken)
    assert (found.name if found else None) == expected


def test_unknown_key_and_bad_pose_name_the_place():
    with pytest.raises(ConfigError, match=r"GUELLY_DELLY.*unknown key\(s\) colour"):
        parse_places({"places": [{"name": "GUELLY_DELLY", "pose": [0, 0, 0], "colour": "red"}]}, "w.yaml")
    with pytest.raises(ConfigError, match=r"\(CAFE\): pose: expected"):
        parse_places({"places": [{"name": "CAFE", "pose": "here"}]}, "w.yaml")


def test_pose_in_wall_or_outside_map_is_refused():
    data = np.zeros((20, 20), dtype=np.int8)
    data[10, :] = 100
    grid = grid_of(data, 0.1)
    ok = parse_places({"places": [{"name": "A", "pose": [0.5, 0.5, 0]}]}, "w.yaml")
    validate_places(ok, grid)
    bad = parse_places(
        {"places": [{"name": "WALL", "pose": [0.5, 1.05, 0]}, {"name": "AWAY", "pose": [9, 9, 0]}]}, "w.yaml"
    )
    with pytest.raises(ConfigError, match=r"WALL .* inside a wall; AWAY .* outside the map"):
        validate_places(bad, grid)
