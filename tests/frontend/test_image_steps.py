"""The keyframe steps a straight pipe's image motion shows, against the map's."""

import numpy as np
import pytest

from pipemap.frontend.tracks import Keyframe
from pipemap.geometry.cylinder import Cylinder
from pipemap.geometry.rotations import exp_so3
from pipemap.frontend.image_steps import image_step, step_disagreement

RADIUS = 0.15


def _keyframes(steps_m, offset=(0.0, 0.0), half_fov_deg=50.0, turn_deg=0.3, seed=0):
    """Keyframes of a camera driving along a pipe on z (radius RADIUS), its centre `offset` (m) off the axis,
    turning by a wobble of up to `turn_deg` a keyframe: exact bearings of wall points within `half_fov_deg`
    of its optical axis, tracks followed from keyframe to keyframe; and the true camera centres."""
    rng = np.random.default_rng(seed)
    phi, z = rng.uniform(0, 2 * np.pi, 40000), rng.uniform(0.0, 12.0, 40000)
    X = np.c_[RADIUS * np.cos(phi), RADIUS * np.sin(phi), z]
    ids = np.arange(len(X))
    centres = np.c_[np.full(len(steps_m) + 1, offset[0]), np.full(len(steps_m) + 1, offset[1]),
                    np.concatenate([[0.0], np.cumsum(steps_m)])]
    R_wc = [np.eye(3)]
    for _ in steps_m:
        R_wc.append(exp_so3(np.radians(rng.uniform(-turn_deg, turn_deg, 3))) @ R_wc[-1])
    out = []
    for k, (c, R) in enumerate(zip(centres, R_wc)):
        Xc = (X - c) @ R  # camera frame
        b = Xc / np.linalg.norm(Xc, axis=1, keepdims=True)
        seen = b[:, 2] > np.cos(np.radians(half_fov_deg))
        if k == 0:
            Rel, t = np.eye(3), np.zeros(3)
        else:
            Rel = R.T @ R_wc[k - 1]  # X_this = Rel X_prev + t
            t = R.T @ (centres[k - 1] - c)
            t /= np.linalg.norm(t)
        n = int(seen.sum())
        out.append(Keyframe(k, k, float(k), np.zeros((n, 2)), b[seen], ids[seen], np.full(n, k > 0),
                            np.zeros(n, bool), Rel, t, True))
    poses = np.tile(np.eye(4), (len(centres), 1, 1))
    poses[:, :3, :3] = np.array(R_wc)
    poses[:, :3, 3] = centres
    return out, poses


@pytest.mark.parametrize("offset, half_fov, within", [
    ((0.0, 0.0), 50.0, 0.02),  # a CCTV camera on the axis
    ((0.0, 0.0), 95.0, 0.02),  # a fisheye
    ((0.0, -0.05), 50.0, 0.15),  # a third of the radius below the axis, as a small crawler carries it
])
def test_the_image_motion_shows_the_step(offset, half_fov, within):
    steps = np.full(6, 0.05)
    kfs, _ = _keyframes(steps, offset, half_fov)
    seen = np.array([image_step(a, b, RADIUS) for a, b in zip(kfs[:-1], kfs[1:])])
    assert np.all(np.abs(seen / steps - 1) < within), seen


def test_a_scale_that_shrank_with_its_points_is_told_by_the_image_motion():
    """The map's last 15 steps shrunk to a quarter (its points with them, which the free radius would not see)."""
    steps = np.full(40, 0.05)
    kfs, poses = _keyframes(steps)
    assert step_disagreement(kfs, poses, 0, 40, RADIUS, 10) < 1.05
    shrunk = poses.copy()
    c = poses[:, :3, 3]
    shrunk[25:, :3, 3] = c[25] + 0.25 * (c[25:] - c[25])
    assert step_disagreement(kfs, shrunk, 0, 40, RADIUS, 10) == pytest.approx(4.0, rel=0.05)
    assert step_disagreement(kfs, shrunk, 0, 20, RADIUS, 10) < 1.05  # the part before is as it was


@pytest.mark.parametrize("offset", [(0.0, -0.05), (0.07, 0.06), (0.0, 0.1)])
def test_off_the_axis_the_mapped_wall_makes_the_step_exact(offset):
    """Two thirds of the radius off the axis the camera-on-the-axis reading is 0.69 of the step; with the wall
    the map fitted it is the step."""
    steps = np.full(6, 0.05)
    kfs, poses = _keyframes(steps, offset, 50.0)
    wall = Cylinder(np.zeros(3), np.array([0.0, 0.0, 1.0]), RADIUS)
    seen = np.array([image_step(a, b, RADIUS, ((poses[k, :3, :3], poses[k, :3, 3]), wall))
                     for k, (a, b) in enumerate(zip(kfs[:-1], kfs[1:]))])
    assert np.all(np.abs(seen / steps - 1) < 0.01), seen
