import math

from hypothesis import given
from hypothesis import strategies as st

from sage_robot.core.geometry import (
    compose,
    inverse,
    quaternion_to_yaw,
    relative,
    wrap_angle,
    yaw_to_quaternion,
)

coord = st.floats(-100, 100, allow_nan=False)
angle = st.floats(-10, 10, allow_nan=False)
pose = st.tuples(coord, coord, angle)


def close(a, b, tol=1e-6):
    return (
        all(abs(x - y) < tol for x, y in zip(a[:2], b[:2], strict=True))
        and abs(wrap_angle(a[2] - b[2])) < tol
    )


@given(pose)
def test_inverse_cancels(p):
    assert close(compose(p, inverse(p)), (0, 0, 0))


@given(pose, pose)
def test_relative_then_compose(a, b):
    assert close(compose(a, relative(a, b)), b)


@given(angle)
def test_yaw_quaternion_round_trip(yaw):
    assert abs(wrap_angle(quaternion_to_yaw(yaw_to_quaternion(yaw)) - yaw)) < 1e-9


def test_compose_by_hand():
    assert close(compose((1, 2, math.pi / 2), (1, 0, 0)), (1, 3, math.pi / 2))
    assert -math.pi <= wrap_angle(math.pi) < math.pi
