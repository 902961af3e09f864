"""Pure pieces of the web server: password file, sessions, origin check, rate limit, views."""

from __future__ import annotations

import io
import json
import math
import stat
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from sage_robot.core.config import Settings
from sage_robot.core.msgs import BatteryState, LaserScan, Pose2D
from sage_robot.core.msgs import Path as PathMsg
from sage_robot.core.msgs.sim import People, Person
from sage_robot.web import auth, views

from ..support.grids import grid_of


def test_generated_password_is_private_stable_and_printed_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.delenv("SAGE_OPERATOR_PASSWORD", raising=False)
    monkeypatch.setenv("SAGE_STATE_DIR", str(tmp_path))
    first = auth.operator_password(Settings())
    path = tmp_path / auth.PASSWORD_FILE
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    assert first in capsys.readouterr().err
    assert auth.operator_password(Settings()) == first
    assert first not in capsys.readouterr().err  # shown once only
    monkeypatch.setenv("SAGE_OPERATOR_PASSWORD", "from-env")
    assert auth.operator_password(Settings()) == "from-env"


def test_sessions_check_password_and_expire() -> None:
    s = auth.Sessions("pw", ttl_s=0.0)
    assert s.check_password("pw")
    assert not s.check_password("pW")
    assert not s.check_password("")
    token = s.create()
    assert not s.valid(token)  # expired at once
    s = auth.Sessions("pw")
    token = s.create()
    assert s.valid(token)
    assert not s.valid("forged")
    assert not s.valid(None)
    s.revoke(token)
    assert not s.valid(token)


@pytest.mark.parametrize(
    ("origin", "host", "ok"),
    [
        (None, "robot:8000", True),  # not a browser
        ("http://robot:8000", "robot:8000", True),
        ("https://ROBOT:8000", "robot:8000", True),
        ("http://robot:8001", "robot:8000", False),
        ("http://evil.example", "robot:8000", False),
        ("null", "robot:8000", False),
        ("http://kiosk.local", "robot:8000", True),  # listed in web.allowed_origins
    ],
)
def test_origin_check(origin: str | None, host: str, ok: bool) -> None:
    assert auth.origin_allowed(origin, host, ("http://kiosk.local",)) is ok


def test_rate_limiter_allows_a_burst_then_refills(monkeypatch: pytest.MonkeyPatch) -> None:
    now = [100.0]
    monkeypatch.setattr("sage_robot.web.auth.time.monotonic", lambda: now[0])
    lim = auth.RateLimiter(rate_per_min=60.0, burst=3)
    assert [lim.allow("a") for _ in range(4)] == [True, True, True, False]
    assert lim.allow("b")  # per address
    assert lim.retry_after_s("a") == pytest.approx(1.0, abs=0.01)
    now[0] += 1.0
    assert lim.allow("a")
    assert not lim.allow("a")


def test_scan_points_land_in_the_map_frame() -> None:
    # one beam straight ahead of the lidar at 2 m, one at 90° left at 1 m, one invalid
    ranges = np.array([2.0, 1.0, np.inf], dtype=np.float32)
    scan = LaserScan(0.0, "laser", 0.0, math.pi / 2, 0.1, 10.0, ranges)
    robot = (1.0, 2.0, math.pi / 2)  # facing +y
    mount = (0.5, 0.0, 0.0)  # lidar 0.5 m ahead of base_link
    pts = views.scan_points(scan, robot, mount)
    np.testing.assert_allclose(pts, [[1.0, 4.5], [0.0, 2.5]], atol=1e-9)


def test_scan_points_are_thinned_for_phones() -> None:
    scan = LaserScan(0.0, "laser", 0.0, 0.001, 0.1, 10.0, np.full(5000, 3.0, dtype=np.float32))
    assert len(views.scan_points(scan, (0, 0, 0), (0, 0, 0), max_points=100)) == 100


def test_map_png_puts_the_highest_y_on_top() -> None:
    data = np.zeros((4, 3), dtype=np.int8)
    data[0, 0] = 100  # row 0 is the bottom of the map
    data[3, 2] = -1
    grid = grid_of(data, 0.05)
    img = np.asarray(Image.open(io.BytesIO(views.map_png(grid))))
    assert img.shape == (4, 3)
    assert img[3, 0] == 0  # occupied: black, bottom-left of the image
    assert img[0, 2] == views.GRAY_UNKNOWN
    assert img[1, 1] == views.GRAY_FREE


def test_views_json() -> None:
    assert views.battery_json(BatteryState(0.0, 15.2, 0.72))["percentage"] == 72.0
    assert views.battery_json(BatteryState(0.0, 15.2, float("nan")))["percentage"] is None
    path = PathMsg(0.0, "map", tuple(Pose2D(float(i), 0.0, 0.0) for i in range(1000)))
    pts = views.path_json(path, max_points=10)["points"]
    assert len(pts) == 10
    assert pts[0] == [0.0, 0.0]
    assert pts[-1] == [999.0, 0.0]
    people = People(0.0, (Person(1, 1.234, 2.0), Person(2, -3.0, 4.5)))
    assert views.people_points(people) == [[1.23, 2.0], [-3.0, 4.5]]


def test_waypoints_file_is_named_shortly_and_the_shipped_one_is_read_only(tmp_path: Path) -> None:
    from sage_robot.core.config import load_profile
    from sage_robot.web.admin import waypoints_info

    shipped = waypoints_info(Settings())  # no nav.waypoints: the file inside the package
    assert shipped["name"] == "campus/waypoints.yaml"
    assert shipped["shipped"]
    assert not shipped["writable"]
    assert "read-only" in shipped["note"]
    assert "nav.waypoints" in shipped["note"]
    assert shipped["path"].endswith("maps/campus/waypoints.yaml")
    copy = tmp_path / "site" / "waypoints.yaml"
    copy.parent.mkdir()
    own = waypoints_info(load_profile(None, {"nav": {"waypoints": str(copy)}}))
    assert own["name"] == "site/waypoints.yaml"
    assert own["writable"]
    assert not own["shipped"]
    assert own["path"] == str(copy)
    gone = waypoints_info(load_profile(None, {"nav": {"waypoints": str(tmp_path / "no" / "w.yaml")}}))
    assert not gone["writable"]
    assert "cannot be written" in gone["note"]


def test_battery_json_carries_the_seed_face_fields_and_unknown_is_null() -> None:
    from sage_robot.core.msgs import PowerStatus

    known = views.battery_json(BatteryState(1.0, 15.2, 0.72, PowerStatus.CHARGING))
    fields = (known["percentage"], known["pct"], known["is_charging"], known["voltage"])
    assert fields == (72.0, 0.72, True, 15.2)
    unknown = views.battery_json(BatteryState(1.0, math.nan, math.nan, PowerStatus.UNKNOWN))
    assert unknown["percentage"] is None
    assert unknown["pct"] is None
    assert unknown["voltage"] is None
    assert not unknown["is_charging"]
    json.dumps(unknown, allow_nan=False)  # valid JSON for a browser: no NaN


def test_the_seed_face_gets_searching_while_sage_says_navigating() -> None:
    state = {"type": "ui_state", "phase": "navigating", "tts_viseme": 0.0}
    assert views.seed_ui_state(state)["phase"] == "searching"
    assert state["phase"] == "navigating"
    assert views.seed_ui_state(dict(state, phase="speaking"))["phase"] == "speaking"
