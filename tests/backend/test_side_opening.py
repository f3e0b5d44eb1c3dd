"""The side opening of a tee passed straight through: the branch cylinder fitted to points beside the pipe."""

import numpy as np
import pytest

from pipemap.backend.side_opening import branch_residuals, fit_side_opening
from pipemap.geometry.cylinder import Cylinder, axis_frame

R = 0.15


def _wall_points(rng, through: Cylinder, centre_h: float, branches: list[tuple[float, float]], n: int = 4000,
                 noise: float = 0.0005) -> np.ndarray:
    """Points on the through pipe's wall (minus the openings) and on each branch's wall up to 2 radii out;
    branches as (azimuth phi, tilt psi) in radians."""
    frame = axis_frame(through.direction)
    e1, e2, z = frame.T
    h = rng.uniform(centre_h - 4 * R, centre_h + 4 * R, n)
    phi = rng.uniform(-np.pi, np.pi, n)
    main = through.origin + np.outer(h, z) + R * (np.outer(np.cos(phi), e1) + np.outer(np.sin(phi), e2))
    centre = through.origin + centre_h * z
    keep = np.ones(n, bool)
    pts = []
    for az, tilt in branches:
        u = np.cos(tilt) * (np.cos(az) * e1 + np.sin(az) * e2) + np.sin(tilt) * z
        f = axis_frame(u)
        w = main - centre
        keep &= ~((np.linalg.norm(w - np.outer(w @ u, u), axis=1) < R) & (w @ u > 0))  # the opening cut out
        s = rng.uniform(0, 3 * R, n // 4)
        a = rng.uniform(-np.pi, np.pi, n // 4)
        b = centre + np.outer(s, u) + R * (np.outer(np.cos(a), f[:, 0]) + np.outer(np.sin(a), f[:, 1]))
        bh = through.axial(b)
        rho = np.linalg.norm(b - through.origin - np.outer(bh, through.direction), axis=1)
        pts.append(b[rho > R])  # the branch wall outside the through pipe
    P = np.vstack([main[keep]] + pts)
    return P + rng.normal(0, noise, P.shape)


@pytest.fixture
def through():
    return Cylinder([0.2, -0.1, 0.3], [0.6, 0.8, 0.0], R)


def test_jacobian_matches_numerical(through):
    rng = np.random.default_rng(1)
    P = rng.normal(0, 0.3, (20, 3))
    x = np.array([0.4, 0.7, 0.2])
    _, J = branch_residuals(P, through, x, R)
    num = np.zeros_like(J)
    for i in range(3):
        d = np.zeros(3)
        d[i] = 1e-6
        num[:, i] = (branch_residuals(P, through, x + d, R)[0] - branch_residuals(P, through, x - d, R)[0]) / 2e-6
    np.testing.assert_allclose(J, num, atol=1e-7)


@pytest.mark.parametrize("seed,azimuth,tilt", [(1, 1.0, 0.0), (2, -2.5, 0.0), (3, 0.3, np.radians(30))])
def test_tee_placed_along_the_pipe_to_a_millimetre(through, seed, azimuth, tilt):
    rng = np.random.default_rng(seed)
    P = _wall_points(rng, through, 0.8, [(azimuth, tilt)])
    # the guess is off by most of a radius, as the junction frames' middle is
    f = fit_side_opening(P, through, 0.8 + 0.8 * R, huber_m=0.005, mad_k=3.0, outlier_passes=3)
    assert f is not None and f.kind == "tee"
    assert abs(f.h - 0.8) < 1e-3
    np.testing.assert_allclose(f.centre, through.origin + 0.8 * through.direction, atol=1e-3)
    assert abs(np.radians(f.azimuth_deg) - azimuth) < np.radians(0.5)
    assert abs(np.radians(f.tilt_deg) - tilt) < np.radians(0.5)
    assert f.rms_m < 0.001 and f.sigma_h_m < 3e-4


def test_cross_has_two_openings(through):
    rng = np.random.default_rng(4)
    P = _wall_points(rng, through, -0.2, [(0.5, 0.0), (0.5 + np.pi, 0.0)])
    f = fit_side_opening(P, through, -0.2, huber_m=0.005, mad_k=3.0, outlier_passes=3)
    assert f is not None and f.kind == "cross"
    assert abs(f.h + 0.2) < 1e-3


def test_no_opening_where_nothing_branches(through):
    rng = np.random.default_rng(5)
    P = _wall_points(rng, through, 0.0, [])
    # stray points off the wall (mismatched tracks, the far end's fittings) are not a branch
    P = np.vstack([P, through.origin + rng.normal(0, 0.4, (150, 3))])
    assert fit_side_opening(P, through, 0.0, huber_m=0.005, mad_k=3.0, outlier_passes=3, max_sigma_m=0.02 * R) is None
