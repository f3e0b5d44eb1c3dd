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


def _pass_map(points: np.ndarray, through: Cylinder, centre_h: float):
    """A map of one straight-through pass: 30 keyframes along the through axis, every point seen by all of
    them, straight sections before and after a junction section around centre_h."""
    from pipemap.backend.network_map import MappedJunction, MappedSection
    from pipemap.backend.pipe_map import PipeMap
    from pipemap.frontend.tracks import Keyframe

    n = len(points)
    ids = np.arange(n, dtype=np.int64)
    kfs = [Keyframe(k, k, float(k), np.zeros((n, 2)), np.zeros((n, 3)), ids, np.ones(n, bool), np.zeros(n, bool),
                    np.eye(3), np.zeros(3), True) for k in range(30)]
    poses = np.stack([np.eye(4)] * 30)
    poses[:, :3, 3] = through.origin + np.outer(centre_h + np.linspace(-0.6, 0.6, 30), through.direction)
    before = MappedSection(0, 0, 11, through, None, through)
    after = MappedSection(2, 18, 29, through, through, None)
    j = MappedJunction("T1", poses[15, :3, 3].copy(), 15, 12, 17, 0, 2, 0.1, "tee-model")
    return PipeMap.build(kfs, poses, points, ids, [before, after], [j])


def test_evidence_places_a_pass_by_its_opening_and_drops_one_without(through):
    from pipemap.backend.evidence import weigh_junction_evidence
    from pipemap.config import Settings

    rng = np.random.default_rng(6)
    tee = _pass_map(_wall_points(rng, through, 0.8, [(1.0, 0.0)], n=3000), through, 0.8 + 0.5 * R)
    out, dropped = weigh_junction_evidence(tee, Settings())
    assert not dropped and out.junctions[0].method == "side-opening"
    np.testing.assert_allclose(out.junctions[0].centroid, through.origin + 0.8 * through.direction, atol=1e-3)
    assert tee.junctions[0].method == "tee-model"  # the map given is left as it was
    plain = _pass_map(_wall_points(rng, through, 0.8, [], n=3000), through, 0.8)
    out, dropped = weigh_junction_evidence(plain, Settings())
    assert out.junctions == [] and [d.id for d in dropped] == ["T1"]
