"""Which angle a tee's solve is held at (backend/join.py): the nearest tee angle give or take the sockets'
deflection, only where the free solve lands beyond that deflection but near the fitting."""

from __future__ import annotations

import pytest

from pipemap.backend.join import _held_angle
from pipemap.config import Settings


@pytest.mark.parametrize("free, held", [
    (90.3, None),  # within the allowance: the free angle stands
    (89.5, None),
    (88.6, 89.5),  # beyond it: held at the allowance's nearer end
    (91.9, 90.5),
    (87.5, None),  # too far for this fitting (an 87.5 deg junction, a wye)
    (45.0, None),
    (0.2, None),  # a run passed straight through
    (1.4, 0.5),
    (float("nan"), None),
])
def test_held_angle(free, held):
    got = _held_angle(free, Settings())
    assert got == (None if held is None else pytest.approx(held, abs=1e-12))


def test_no_tee_angles_leave_every_angle_free():
    s = Settings()
    s.bundle.tee_angles_deg = []
    assert _held_angle(88.6, s) is None


def test_no_allowance_holds_the_tee_angle_itself():
    s = Settings()
    s.bundle.tee_angle_allowance_deg = 0.0
    assert _held_angle(89.7, s) == 90.0
    assert _held_angle(90.0, s) is None  # already there


def test_on_lagging_footage_the_tee_angle_itself_is_held():
    assert _held_angle(89.7, Settings(), exact=True) == 90.0
    assert _held_angle(88.2, Settings(), exact=True) == 90.0
    assert _held_angle(87.5, Settings(), exact=True) is None  # still only near a tee angle


def test_a_held_angle_lies_between_the_end_cylinders_unless_one_bends_off_its_section():
    import numpy as np

    from pipemap.backend.join import _held_axes
    from pipemap.geometry.cylinder import Cylinder

    def cyl(deg):
        a = np.radians(deg)
        return Cylinder(np.zeros(3), np.array([np.cos(a), np.sin(a), 0.0]), 0.2)

    whole_red, whole_blue = cyl(0.0), cyl(90.0)
    red_end, blue_start = cyl(0.3), cyl(88.5)  # the blue section's start bent 1.5 deg off its axis
    s = Settings()
    red, blue = _held_axes((red_end, blue_start), (whole_red, whole_blue), s)
    assert red is red_end
    np.testing.assert_allclose(blue.direction, whole_blue.direction, atol=1e-12)  # the section's direction ...
    np.testing.assert_allclose(blue.origin, blue_start.origin, atol=1e-12)  # ... through the end fit's axis
    red, blue = _held_axes((red_end, blue_start), (whole_red, whole_blue), s, (None, np.array([0.0, 0.5, 0.0])))
    np.testing.assert_allclose(blue.origin, 0.5 * blue_start.direction * blue_start.direction[1], atol=1e-12)
    s.bundle.tee_hold_axes = "ends"
    assert _held_axes((red_end, blue_start), (whole_red, whole_blue), s) == (red_end, blue_start)
    s.bundle.tee_hold_axes = "sections"
    red, blue = _held_axes((red_end, blue_start), (whole_red, whole_blue), s)
    np.testing.assert_allclose(red.direction, whole_red.direction, atol=1e-12)
    assert _held_axes((red_end, blue_start), (None, None), s) == (red_end, blue_start)
