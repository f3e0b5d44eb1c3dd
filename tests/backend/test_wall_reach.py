"""How far ahead the wall is still the straight cylinder beside the camera (backend/wall_reach.py)."""

import numpy as np
import pytest

from pipemap.backend.wall_reach import straight_reach

R = 0.15
CAMERA = np.array([0.0, 0.0, 0.0])
AHEAD = np.array([0.0, 0.0, 1.0])


def _straight(rng, z0: float, z1: float, n: int) -> np.ndarray:
    z, phi = rng.uniform(z0, z1, n), rng.uniform(-np.pi, np.pi, n)
    return np.column_stack([R * np.cos(phi), R * np.sin(phi), z])


def _bend(rng, start: float, bend_radius: float, angle_deg: float, n: int) -> np.ndarray:
    """Wall of a bend that leaves the pipe along z at z = start, turning towards +x."""
    a, phi = rng.uniform(0, np.radians(angle_deg), n), rng.uniform(-np.pi, np.pi, n)
    axis = np.column_stack([bend_radius * (1 - np.cos(a)), np.zeros(n), start + bend_radius * np.sin(a)])
    inward = np.column_stack([np.cos(a), np.zeros(n), -np.sin(a)])
    return axis + R * (np.cos(phi)[:, None] * inward + np.sin(phi)[:, None] * np.array([0.0, 1.0, 0.0]))


def _reach(points, rng, noise_m=0.0003):
    return straight_reach(points + rng.normal(0, noise_m, points.shape), CAMERA, AHEAD, R, inward_m=0.001,
                          slice_m=0.04, huber=0.005)


@pytest.mark.parametrize("bend_radius", [0.3, 0.45, 0.9])
def test_the_wall_ahead_ends_where_a_bend_begins(bend_radius):
    rng = np.random.default_rng(3)
    start = 0.3
    points = np.vstack([_straight(rng, -0.6, start, 6000), _bend(rng, start, bend_radius, 45, 3000)])
    reach = _reach(points, rng)
    # the bend's outer wall comes in by 1 mm sqrt(2 R_bend 1 mm) into the bend: 2.4-4.2 cm; a slice is 4 cm long
    assert start - 0.04 <= reach <= start + np.sqrt(2 * bend_radius * 0.001)


def test_a_straight_pipe_with_a_branch_ahead_runs_on():
    """A tee passed straight through: the branch's wall lies beyond the pipe's, none comes in."""
    rng = np.random.default_rng(4)
    main = _straight(rng, -0.6, 0.8, 9000)
    opening = (main[:, 0] > 0) & (np.abs(main[:, 2] - 0.4) < R)
    phi = rng.uniform(-np.pi, np.pi, 3000)
    branch = np.column_stack([rng.uniform(0, 0.6, 3000), R * np.cos(phi), 0.4 + R * np.sin(phi)])
    branch = branch[np.hypot(branch[:, 0], branch[:, 1]) > R]  # outside the main pipe
    reach = _reach(np.vstack([main[~opening], branch]), rng)
    assert reach == np.inf


def test_a_straight_pipe_runs_on_through_noisy_points():
    rng = np.random.default_rng(5)
    assert _reach(_straight(rng, -0.6, 0.6, 8000), rng, noise_m=0.001) == np.inf


def test_pieces_offset_behind_the_camera_do_not_cut_the_wall_ahead():
    """A run's pieces meet with millimetre offsets: the wall ahead is judged against the wall just behind the
    camera, not against a cylinder through metres of offset pieces."""
    rng = np.random.default_rng(6)
    far_piece = _straight(rng, -2.5, -0.8, 12000) + np.array([0.004, 0.0, 0.0])
    near = _straight(rng, -0.8, 0.6, 9000)
    assert _reach(np.vstack([far_piece, near]), rng) == np.inf


def test_the_bend_cut_is_off_on_predicted_video():
    """On H.264 the codec's lag brings the wall just ahead of the newest keyframe in by sector, and the cut made
    there shortened a straight pipe's windows (fisheye-straight seed 2: -0.054 -> -0.271 %): predicted video keeps
    the whole wall ahead; images and intra-coded video keep the cut, and the user's own setting stands."""
    from types import SimpleNamespace

    from pipemap.config import Settings
    from pipemap.pipeline import straight_vo_settings

    s = Settings()
    assert s.straight_vo.wall_inward_m == 0.001
    on_video = straight_vo_settings(s, SimpleNamespace(predicted=True))
    assert on_video.straight_vo.wall_inward_m is None
    assert on_video.straight_vo.wall_slice_m == s.straight_vo.wall_slice_m and on_video.bundle == s.bundle
    assert s.straight_vo.wall_inward_m == 0.001  # the run's own settings are left as they were
    assert straight_vo_settings(s, SimpleNamespace(predicted=False)) is s
    s.straight_vo.wall_inward_m = 0.002
    assert straight_vo_settings(s, SimpleNamespace(predicted=False)).straight_vo.wall_inward_m == 0.002
