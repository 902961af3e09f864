import os

import pytest

from sage_robot.core.config import load_profile, parse_profile, read_secret
from sage_robot.core.errors import ConfigError


def test_shipped_profile_loads_with_seed_defaults():
    s = load_profile()
    assert s.robot.track_width_m == 0.381
    assert s.robot.radius_m == 0.25
    assert (s.robot.lidar.x_m, s.robot.lidar.z_m) == (0.1466, 0.527)
    assert s.robot.max_linear_mps == 0.8
    assert s.robot.max_angular_radps == 1.0
    assert s.mcu.baud == 115200
    assert s.mcu.watchdog_s == 0.55
    assert s.nav.inflation_radius_m == 0.55


def test_settings_are_frozen():
    s = load_profile()
    with pytest.raises(Exception, match="frozen"):
        s.robot.radius_m = 1.0  # type: ignore[misc]


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("robot:\n  radius_m: wide\n", r"p.yaml: robot.radius_m \(line 2\): .*number.*'wide'"),
        ("robot:\n  radius_m: -1\n", r"robot.radius_m \(line 2\): .*greater than 0"),
        ("robot:\n  raduis_m: 0.3\n", r"robot.raduis_m \(line 2\): unknown key"),
        ("nav: [1, 2\n", r"p.yaml: line \d+, column \d+: not valid YAML"),
        ("- just\n- a list\n", r"expected a mapping of sections"),
        ("battery:\n  discharge_curve: [[16, 1.0], [12, 0.0]]\n", r"increasing voltage"),
    ],
)
def test_each_mistake_gets_one_clear_message(text, expected):
    with pytest.raises(ConfigError, match=expected):
        parse_profile(text, "p.yaml")


def test_missing_file_is_named(tmp_path):
    with pytest.raises(ConfigError, match="profile not found"):
        load_profile(tmp_path / "nope.yaml")


def test_overrides_do_not_touch_the_callers_dict():
    over = {"sim": {"speed": None}}
    s = load_profile(None, over)
    assert s.sim.speed is None
    assert over == {"sim": {"speed": None}}


def test_secret_from_env_and_owner_only_key_file(tmp_path, monkeypatch):
    monkeypatch.delenv("SAGE_TEST_KEY", raising=False)
    f = tmp_path / "keys.env"
    f.write_text("SAGE_TEST_KEY=sk-123\n")
    os.chmod(f, 0o644)
    with pytest.raises(ConfigError, match="chmod 600"):
        read_secret("SAGE_TEST_KEY", f)
    os.chmod(f, 0o600)
    secret = read_secret("SAGE_TEST_KEY", f)
    assert secret is not None
    assert secret.get_secret_value() == "sk-123"
    assert "sk-123" not in repr(secret)
    assert "sk-123" not in str(secret)
    monkeypatch.setenv("SAGE_TEST_KEY", "from-env")
    assert read_secret("SAGE_TEST_KEY", f).get_secret_value() == "from-env"  # type: ignore[union-attr]
