"""Round trip of every registered message through the JSON codec (STYLE 1)."""

import json

import numpy as np
import pytest

import sage_robot.core.msgs as msgs
from sage_robot.core.msgs import REGISTRY, from_dict, nav, to_dict

EXAMPLES = [
    msgs.Twist(0.5, -0.2),
    msgs.Pose2D(1.0, 2.0, 0.3),
    msgs.PoseWithCovariance(1.5, "map", msgs.Pose2D(1, 2, 3), tuple(float(i) for i in range(9))),
    msgs.PoseStamped(2.0, "map", msgs.Pose2D(4, 5, 6)),
    msgs.Odometry(3.0, msgs.Pose2D(1, 1, 1), msgs.Twist(0.2, 0.1)),
    msgs.Imu(4.0, (0.1, 0.2, 0.3), (0.0, 0.0, 9.81)),
    msgs.BatteryState(5.0, 15.1, 0.7, msgs.PowerStatus.CHARGING),
    msgs.LaserScan(
        6.0, "laser", -3.14, 0.0174, 0.15, 12.0, np.array([1.0, np.inf, 2.5], dtype=np.float32)
    ),
    msgs.OccupancyGrid(
        7.0, "map", 0.05, msgs.Pose2D(-1, -2, 0), np.array([[-1, 0], [100, 50]], dtype=np.int8)
    ),
    msgs.Path(8.0, "map", (msgs.Pose2D(0, 0, 0), msgs.Pose2D(1, 0, 0))),
    msgs.CompressedImage(9.0, "camera", "jpeg", b"\xff\xd8\xff\x00"),
    msgs.DiagnosticStatus("mcu", msgs.Level.WARN, "reconnecting", {"port": "/dev/ttyACM0"}),
    msgs.DiagnosticArray(10.0, (msgs.DiagnosticStatus("a", msgs.Level.OK, "fine"),)),
    msgs.Text("hello"),
    msgs.Utterance("where is the cafe?", "web:127.0.0.1"),
    msgs.Event(11.0, "nav", "arrived", "at the cafe", {"place": "GUELLY_DELLY"}),
    msgs.EStopState(True, "operator"),
    msgs.NodeHealth("web", "running", 1, "", 2.5, True, {"clients": 2}, {"/sage/ui_state": 4.0}),
    msgs.HealthReport(12.0, (msgs.NodeHealth("mcu_sim", "backoff", last_error="boom"),)),
    nav.NavigateGoal(place="the cafe"),
    nav.NavigateGoal(pose=msgs.Pose2D(1, 2, 3)),
    nav.NavigateFeedback(nav.NavState.WAITING_FOR_PEOPLE, "GUELLY_DELLY", 12.5, 30.0),
    nav.NavigateResult(False, "CLEAN_ROOM", "the corridor to the clean room is blocked", 3.5, 20.0),
    nav.TourGoal(("GUELLY_DELLY", "CLEAN_ROOM"), 15.0, 1),
    nav.TourFeedback(1, "CLEAN_ROOM", nav.NavState.DRIVING),
    nav.TourResult(("GUELLY_DELLY",), False, "canceled"),
    nav.PlaceInfo("CLEAN_ROOM", msgs.Pose2D(5, 6, 0), "controlled environment", ("the clean room",)),
    nav.PlaceList((nav.PlaceInfo("A", msgs.Pose2D()),)),
    nav.WhereAmI(msgs.Pose2D(1, 1, 0), "HESSE_CENTER", 2.5, True),
    nav.LocalizationHealth(3.0, 0.93, False, 1200),
]


@pytest.mark.parametrize("msg", EXAMPLES, ids=lambda m: type(m).__name__)
def test_round_trip_through_json(msg):
    wire = json.dumps(to_dict(msg))
    assert from_dict(json.loads(wire)) == msg


def test_every_core_message_has_an_example():
    covered = {type(m).__name__ for m in EXAMPLES}
    mine = ("sage_robot.core.msgs.std", "sage_robot.core.msgs.nav")
    core = {n for n, c in REGISTRY.items() if c.__module__ in mine}
    assert core <= covered, f"add round-trip examples for {sorted(core - covered)}"


def test_bad_input_names_the_problem():
    with pytest.raises(ValueError, match="unknown message type"):
        from_dict({"type": "Nope"})
    with pytest.raises(ValueError, match=r"Twist.linear_x: expected a number"):
        from_dict({"type": "Twist", "linear_x": "fast", "angular_z": 0})
    with pytest.raises(ValueError, match="missing field 'pose'"):
        from_dict({"type": "PoseStamped", "stamp": 1.0, "frame_id": "map"})


def test_messages_are_frozen():
    t = msgs.Twist(1.0, 0.0)
    with pytest.raises(AttributeError):
        t.linear_x = 2.0  # type: ignore[misc]
