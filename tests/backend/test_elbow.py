"""Elbows: the bend radius fitted to the wall of the bend, and no pipe beyond the vertex."""

import numpy as np
import pytest

from pipemap.backend.elbow import bend_of, bend_residuals, fit_bend_radius, on_arc, pipe_beyond
from pipemap.geometry.cylinder import Cylinder

R = 0.15


def _elbow_points(rng, angle_deg: float, rho: float, n: int = 6000, noise: float = 0.0005, through: bool = False):
    """Wall points of a pipe along -x into the vertex at the origin, turning by angle_deg in the xy plane on an arc
    of radius rho, and out along the second axis; with `through`, the first pipe also runs on past the vertex
    (a tee's main pipe, with the second as its branch). Returns the points and the two straight cylinders."""
    th = np.radians(angle_deg)
    d1, d2 = np.array([1.0, 0, 0]), np.array([np.cos(th), np.sin(th), 0.0])
    T = rho * np.tan(th / 2)
    C = -T * d1 + rho * np.array([0, 1.0, 0])
    a = rng.uniform(0, th, n)
    w = rng.uniform(-np.pi, np.pi, n)
    radial = np.stack([np.sin(a), -np.cos(a), np.zeros(n)], axis=1)  # from C to the axis circle
    axis_pts = C + rho * radial
    torus = axis_pts + R * (np.cos(w)[:, None] * radial + np.sin(w)[:, None] * np.array([0, 0, 1.0]))
    def straight(start, d, length, m):
        h = rng.uniform(0, length, m)
        f = np.cross(d, [0, 0, 1.0])
        f /= np.linalg.norm(f)
        ww = rng.uniform(-np.pi, np.pi, m)
        return start + np.outer(h, d) + R * (np.outer(np.cos(ww), f) + np.outer(np.sin(ww), [0, 0, 1.0]))
    parts = [torus, straight(-T * d1 - 1.0 * d1, d1, 1.0, n), straight(T * d2, d2, 1.0, n)]
    if through:
        parts.append(straight(np.zeros(3), d1, 0.6, n))
    P = np.vstack(parts) + rng.normal(0, noise, (len(parts) * n, 3))
    return P, Cylinder(-T * d1 - 0.5 * d1, d1, R), Cylinder(T * d2 + 0.5 * d2, d2, R)


def test_bend_jacobian_matches_numerical():
    rng = np.random.default_rng(0)
    P, a, b = _elbow_points(rng, 70.0, 0.5, n=50)
    bend = bend_of(a, b, np.zeros(3))
    _, J = bend_residuals(P, bend, 0.4, R)
    num = (bend_residuals(P, bend, 0.4 + 1e-6, R)[0] - bend_residuals(P, bend, 0.4 - 1e-6, R)[0]) / 2e-6
    np.testing.assert_allclose(J[:, 0], num, atol=1e-7)


@pytest.mark.parametrize("seed,angle,rho", [(1, 90.0, 0.45), (2, 45.0, 0.6), (3, 30.0, 3.0)])
def test_bend_radius_within_half_a_percent(seed, angle, rho):
    rng = np.random.default_rng(seed)
    P, a, b = _elbow_points(rng, angle, rho)
    bend = bend_of(a, b, np.zeros(3))
    assert abs(bend.angle_deg - angle) < 1e-9
    np.testing.assert_allclose(bend.centre(rho)[:2], [-rho * np.tan(np.radians(angle) / 2), rho], atol=1e-12)
    assert on_arc(P, bend, rho).sum() > 1000
    fit = fit_bend_radius(P, bend, R, huber_m=0.005, mad_k=3.0, outlier_passes=3)
    assert fit is not None
    assert abs(fit.bend_radius_m - rho) < 0.005 * rho
    assert fit.rms_m < 0.001


def test_a_tee_has_pipe_beyond_its_vertex_and_an_elbow_none():
    rng = np.random.default_rng(4)
    P, a, b = _elbow_points(rng, 90.0, 0.45)
    bend = bend_of(a, b, np.zeros(3))
    assert max(pipe_beyond(P, a, b, bend, 0.02)) == 0
    P, a, b = _elbow_points(rng, 90.0, 0.45, through=True)
    on_a, on_b = pipe_beyond(P, a, b, bend, 0.02)
    assert on_a > 1000 and on_b == 0


def test_a_cross_has_pipe_beyond_its_vertex_on_both_sides():
    rng = np.random.default_rng(5)
    P, a, b = _elbow_points(rng, 90.0, 0.45, through=True)
    bend = bend_of(a, b, np.zeros(3))
    d2 = bend.d2
    f = np.cross(d2, [0, 0, 1.0])
    h = rng.uniform(0, 0.6, 3000)
    w = rng.uniform(-np.pi, np.pi, 3000)
    opposite = np.outer(-h, d2) + 0.15 * (np.outer(np.cos(w), f) + np.outer(np.sin(w), [0, 0, 1.0]))
    on_a, on_b = pipe_beyond(np.vstack([P, opposite]), a, b, bend, 0.02)
    assert on_a > 1000 and on_b > 1000


def test_bend_normals_match_numerical():
    from pipemap.backend.elbow import bend_normals

    rng = np.random.default_rng(4)
    P, a, b = _elbow_points(rng, 60.0, 0.5, n=40, noise=0.01)
    bend = bend_of(a, b, np.zeros(3))
    J = bend_normals(P, bend, 0.5)
    num = np.stack([(bend_residuals(P + e, bend, 0.5, R)[0] - bend_residuals(P - e, bend, 0.5, R)[0]) / 2e-6
                    for e in np.eye(3) * 1e-6], axis=1)
    np.testing.assert_allclose(J, num, atol=1e-6)


def _tee_corner_points(rng, n: int = 6000, stub: int = 20, noise: float = 0.0005):
    """A tee's wall as a camera turning from its run into its branch sees it: the run along +x up to the vertex at
    the origin, the branch leaving along +y from the run's wall, and only `stub` points on the run past the vertex.
    Returns the points and the two straight cylinders."""
    def pipe(start, d, length, m):
        h = rng.uniform(0, length, m)
        f = np.cross(d, [0, 0, 1.0])
        w = rng.uniform(-np.pi, np.pi, m)
        return start + np.outer(h, d) + R * (np.outer(np.cos(w), f) + np.outer(np.sin(w), [0, 0, 1.0]))
    x, y = np.array([1.0, 0, 0]), np.array([0, 1.0, 0])
    run = pipe(-1.0 * x, x, 1.0, n)
    run = run[~((run[:, 1] > 0) & (np.abs(run[:, 0]) < R))]  # the branch's mouth
    branch = pipe(np.zeros(3), y, 1.0, n)
    branch = branch[branch[:, 1] ** 2 + branch[:, 2] ** 2 > R ** 2]  # inside the run
    P = np.vstack([run, branch, pipe(np.zeros(3), x, 0.6, stub)])
    return P + rng.normal(0, noise, P.shape), Cylinder(-0.5 * x, x, R), Cylinder(0.5 * y, y, R)


@pytest.mark.parametrize("seed", [6, 7])
def test_a_tee_whose_run_on_pipe_shows_few_points_is_no_elbow(seed):
    """Too few points past the vertex to show the run-on pipe: the wall's corner fits a bend radius under the pipe's
    radius, tighter than any elbow made, and the pass stays a tee; a true elbow's stays an elbow, a short-radius one
    (one diameter) included."""
    from pipemap.backend.evidence import pass_type
    rng = np.random.default_rng(seed)
    P, a, b = _tee_corner_points(rng)
    bend = bend_of(a, b, np.zeros(3))
    beyond = pipe_beyond(P, a, b, bend, 0.02)
    assert max(beyond) < 30
    fit = fit_bend_radius(P, bend, R, huber_m=0.005, mad_k=3.0, outlier_passes=3)
    rho = float("nan") if fit is None else fit.bend_radius_m
    assert pass_type(beyond, rho, R, 30) == "tee"
    P, a, b = _elbow_points(rng, 90.0, 0.45)
    bend = bend_of(a, b, np.zeros(3))
    fit = fit_bend_radius(P, bend, R, huber_m=0.005, mad_k=3.0, outlier_passes=3)
    assert abs(fit.bend_radius_m - 0.45) < 0.005 * 0.45
    assert pass_type(pipe_beyond(P, a, b, bend, 0.02), fit.bend_radius_m, R, 30) == "elbow"
    # a short-radius elbow (one diameter) found 5 % tight stays an elbow: the limit sits halfway, at 0.75 D
    P, a, b = _elbow_points(rng, 90.0, 2 * R)
    bend = bend_of(a, b, np.zeros(3))
    fit = fit_bend_radius(P, bend, R, huber_m=0.005, mad_k=3.0, outlier_passes=3)
    assert abs(fit.bend_radius_m - 2 * R) < 0.005 * 2 * R
    beyond = pipe_beyond(P, a, b, bend, 0.02)
    assert pass_type(beyond, fit.bend_radius_m, R, 30) == "elbow"
    assert pass_type(beyond, 0.95 * fit.bend_radius_m, R, 30) == "elbow"
