"""Exact ray casting against the union of cylinders: on the wall, outside the others, nearest."""

import numpy as np
import pytest

from conftest import LOOP_CORNERS
from pipemap.sim.network_model import PipeScene
from pipemap.sim.raycast import RayCaster

R = 0.2


def random_rays(n, seed):
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def loop_origins():
    """Camera centres inside the loop: mid-side, near a joint, inside tees, beside a stub."""
    return [np.array(p) for p in ([1.5, 0.02, -0.04], [1.0, 0.0, -0.1], [2.85, 0.05, -0.04], [3.02, 0.1, -0.03],
                                  [3.2, -0.05, 0.0], [0.0, 1.0, 0.05], [0.1, 1.95, -0.05])]


def radial_error(scene: PipeScene, points, pipe_idx, cap):
    err = np.zeros(len(points))
    for k, p in enumerate(scene.pipes):
        m = (pipe_idx == k) & ~cap
        q = points[m] - p.start
        h = q @ p.axis
        err[m] = np.abs(np.linalg.norm(q - h[:, None] * p.axis, axis=1) - scene.radius)
    return err


def inside_other(scene: PipeScene, points, pipe_idx, tol=1e-7):
    bad = np.zeros(len(points), bool)
    for k, p in enumerate(scene.pipes):
        q = points - p.start
        h = q @ p.axis
        rad = np.linalg.norm(q - h[:, None] * p.axis, axis=1)
        bad |= ((pipe_idx != k) & (h > -p.extend_start + tol) & (h < p.length + p.extend_end - tol)
                & (rad < scene.radius - tol))
    return bad


def brute_force(scene: PipeScene, origin, d):
    """Independent reference: every lateral root and cap of every piece, kept when on the
    union's boundary, nearest first (no culling, no fast path)."""
    best = np.full(len(d), np.inf)
    for p in scene.pipes:
        u, w = p.axis, origin - p.start
        du, wu = d @ u, w @ u
        A = 1 - du**2
        B = 2 * (d @ w - du * wu)
        C = w @ w - wu**2 - scene.radius**2
        disc = B**2 - 4 * A * C
        with np.errstate(invalid="ignore", divide="ignore"):
            ts = [(-B - np.sqrt(disc)) / (2 * A), (-B + np.sqrt(disc)) / (2 * A)]
            for end, closed in ((0.0, p.closed_start), (p.length, p.closed_end)):
                if closed:
                    ts.append((end - wu) / du)
        for j, t in enumerate(ts):
            t = np.where(np.isfinite(t) & (t > 1e-12), t, np.inf)
            P = origin + np.where(np.isfinite(t), t, 0)[:, None] * d
            q = P - p.start
            h = q @ u
            rad = np.linalg.norm(q - h[:, None] * u, axis=1)
            if j < 2:
                ok = (h >= -p.extend_start - 1e-9) & (h <= p.length + p.extend_end + 1e-9)
            else:
                ok = rad <= scene.radius + 1e-12
            own = np.full(len(d), scene.pipes.index(p))
            ok &= ~inside_other(scene, P, own, tol=1e-9)
            best = np.where(ok & (t < best), t, best)
    return best


@pytest.mark.parametrize("k", range(7))
def test_loop_hits_are_exact_on_the_union_boundary(loop_scene, k):
    origin = loop_origins()[k]
    assert loop_scene.contains(origin[None])[0]
    caster = RayCaster(loop_scene, dtype=np.float64, max_hops=99, cull_distance_m=1e3)
    d = random_rays(20000, k)
    hits = caster.cast_world(origin, d)
    assert hits.hit.all()  # a closed network: every ray ends on a wall or an end cap
    P = origin + hits.t[:, None] * d
    assert radial_error(loop_scene, P, hits.pipe, hits.cap).max() < 1e-9  # on the cylinder to 1e-9 m
    assert not inside_other(loop_scene, P, hits.pipe).any()
    # the segment from the camera to the hit never leaves the union
    for frac in (0.25, 0.5, 0.75, 0.99):
        assert loop_scene.contains(origin + frac * hits.t[:, None] * d, tol=-1e-9).all()


@pytest.mark.parametrize("k", [0, 2, 3, 4])
def test_loop_hit_is_the_nearest_valid_boundary_point(loop_scene, k):
    origin = loop_origins()[k]
    d = random_rays(3000, 100 + k)
    hits = RayCaster(loop_scene, dtype=np.float64, max_hops=99, cull_distance_m=1e3).cast_world(origin, d)
    ref = brute_force(loop_scene, origin, d)
    np.testing.assert_allclose(hits.t, ref, rtol=0, atol=1e-9)


def test_straight_pipe_caps_and_far_end(straight):
    caster = RayCaster(straight, dtype=np.float64)
    origin = np.array([1.0, 0.01, -0.04])
    d = np.array([[1.0, 0.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    hits = caster.cast_world(origin, d)
    assert hits.cap[:2].all() and not hits.cap[2]
    end = straight.pipes[-1]
    far = origin + hits.t[0] * d[0]
    assert abs((far - end.start) @ end.axis - end.length) < 1e-9  # on the closing disc
    assert abs(hits.t[1] - 1.0) < 1e-3  # the start cap at x = 0 (the first piece sags a little)
    assert 0.23 < hits.t[2] < 0.25  # the wall above: ~0.2 m from an axis ~0.04 m above the camera


def test_tee_shows_the_branch_opening(loop_scene):
    caster = RayCaster(loop_scene, dtype=np.float64)
    origin = np.array([2.6, 0.0, -0.04])  # in S1, 0.4 m before T2 (3, 0, 0); S2 is the branch
    ahead = np.array([1.0, 0.6, 0.1])
    d = random_rays(40000, 9)
    d = d[d @ ahead > 0.5]
    hits = caster.cast_world(origin, d)
    ids = np.array([p.id for p in loop_scene.pipes])[hits.pipe]
    assert np.mean(np.char.startswith(ids, "S2")) > 0.02  # the branch is seen through its opening
    assert np.mean(ids == "B2") > 0.02  # and the stub straight ahead, with its closed end
    assert hits.cap[ids == "B2"].any()


@pytest.mark.parametrize("origin", [np.array([1.5, 0.02, -0.04]), np.array([3.02, 0.1, -0.03])])
def test_float32_casting_agrees_with_float64(loop_scene, origin):
    d = random_rays(20000, 3)
    h64 = RayCaster(loop_scene, dtype=np.float64).cast_world(origin, d)
    h32 = RayCaster(loop_scene, dtype=np.float32).cast_world(origin, d)
    same = h32.pipe == h64.pipe
    assert same.mean() > 0.995  # rays exactly on a seam may pick either piece
    assert np.abs(h32.t[same] - h64.t[same]).max() < 2e-4  # metres, float32 rounding
    assert abs(np.median(np.abs(h32.t - h64.t))) < 1e-5


def test_corners_match_the_scene(loop_scene):
    ids = [j.id for j in loop_scene.junctions]
    assert ids == ["T1", "T2", "T3", "T4"]
    np.testing.assert_allclose([j.centroid for j in loop_scene.junctions], LOOP_CORNERS)
