"""Elbows (torus pieces) and crosses in the renderer: exact ray-torus hits, the wall's texture coordinates
running on unbroken into a bend, routes that follow an elbow's arc (issue 20)."""

import numpy as np
import pytest

from pipemap.geometry.torus import quartic_real_roots, ray_torus
from pipemap.sim.presets import elbow_cross_scene
from pipemap.sim.raycast import RayCaster
from pipemap.sim.render import Appearance, Renderer
from pipemap.sim.presets import fisheye_camera
from pipemap.sim.simulate import plan

R_PIPE = 0.15


@pytest.fixture(scope="module")
def scene():
    return elbow_cross_scene(R_PIPE)


def _sphere(n, seed):
    d = np.random.default_rng(seed).normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def test_quartic_roots_against_known_roots():
    rng = np.random.default_rng(0)
    roots = np.sort(rng.uniform(-5, 5, (20000, 4)), axis=1)
    r0, r1, r2, r3 = roots.T
    a = -(r0 + r1 + r2 + r3)
    b = r0 * r1 + r0 * r2 + r0 * r3 + r1 * r2 + r1 * r3 + r2 * r3
    c = -(r0 * r1 * r2 + r0 * r1 * r3 + r0 * r2 * r3 + r1 * r2 * r3)
    d = r0 * r1 * r2 * r3
    found = np.sort(quartic_real_roots(a, b, c, d), axis=1)
    # well separated roots (> 1e-3 apart) come back to 1e-9 after Newton polishing
    sep = np.min(np.diff(roots, axis=1), axis=1) > 1e-3
    assert np.abs(found[sep] - roots[sep]).max() < 1e-9
    # x^4 + 1 has no real root
    assert np.isnan(quartic_real_roots(0.0, 0.0, 0.0, 1.0)).all()


def test_ray_torus_hits_lie_on_the_torus():
    o = np.array([1.02, 0.03, -0.05])  # inside the tube of minor radius 0.3
    d = _sphere(50000, 1).T
    t = ray_torus(o, d, 0.3)
    p = o[:, None, None] + d[:, :, None] * t[None]
    dist = np.hypot(np.hypot(p[0], p[1]) - 1.0, p[2])
    assert np.nanmax(np.abs(dist - 0.3)) < 1e-12  # in bend radii: 1e-12 R
    # from inside the tube every ray leaves it: one root behind, one ahead at least
    assert np.all(np.nanmax(t, axis=1) > 0) and np.all(np.nanmin(t, axis=1) < 0)


@pytest.mark.parametrize("where", [("E1.arc", 0.5), ("E2.arc", 0.3), ("E3.arc", 0.7)])
def test_float64_casts_from_inside_a_bend_hit_its_wall(scene, where):
    bend = next(b for b in scene.bends if b.id == where[0])
    origin = bend.axis_point(where[1] * bend.angle) + np.array([0.0, 0.0, -0.04])
    caster = RayCaster(scene, dtype=np.float64)
    dirs = _sphere(20000, 2)
    hits = caster.cast_world(origin, dirs)
    assert hits.hit.all()  # a closed network: every ray ends on some wall
    pts = origin + hits.t[:, None] * dirs
    k = len(scene.pipes) + scene.bends.index(bend)
    on = hits.pipe == k
    assert on.mean() > 0.3
    theta, d = bend.tube_coordinates(pts[on])
    # a bend's hit is on its torus to 1e-9 m, within its angle (widened by the 1e-10 m seam tolerance)
    assert np.abs(d - R_PIPE).max() < 1e-9
    assert theta.min() > -1e-9 and theta.max() < bend.angle + 1e-9
    # h is the chainage along the arc
    np.testing.assert_allclose(hits.h[on], bend.bend_radius * theta, atol=1e-9)
    # every hit is on the boundary of the union: just before it inside, just beyond it outside
    assert scene.contains(origin + (hits.t[:, None] - 1e-6) * dirs).all()
    assert not scene.contains(origin + (hits.t[:, None] + 1e-6) * dirs).any()


def test_cross_is_open_in_all_four_directions(scene):
    x1 = next(j.centroid for j in scene.junctions if j.id == "X1")
    caster = RayCaster(scene, dtype=np.float64)
    dirs = np.array([[1.0, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1]])
    hits = caster.cast_world(x1, dirs)
    # +x: the stub's closed end 1 m away; +y: the main pipe's end 1 m away; -x: the branch's wall where E2
    # turns it (beyond its 0.95 m straight piece); -y: back along the main pipe to E1's arc beyond 1.75 m
    assert hits.t[0] == pytest.approx(1.0, abs=1e-9) and hits.cap[0]
    assert hits.t[2] == pytest.approx(1.0, abs=1e-9) and hits.cap[2]
    assert hits.t[1] > 0.95 and hits.t[3] > 1.75
    assert hits.t[4] == pytest.approx(R_PIPE, abs=1e-9)  # the crown above the centre


def test_route_follows_the_elbows_arcs(scene):
    p = plan("elbow-cross", route="A")
    path = p.path
    for b in scene.bends:
        k = int(np.flatnonzero(np.linalg.norm(path.vertices - next(
            j.centroid for j in scene.junctions if j.id == b.junction), axis=1) < 1e-9)[0])
        s_mid = path.vertex_s[k]
        half = b.bend_radius * b.angle / 2
        pos, _ = path.evaluate(np.linspace(s_mid - half, s_mid + half, 101))
        # the axis path runs along the torus's axis circle (to 1e-9 m), arc length = bend radius x angle
        theta, d = b.tube_coordinates(pos)
        assert np.abs(d).max() < 1e-9
        np.testing.assert_allclose(theta[[0, -1]], [0.0, b.angle], atol=1e-9)
    assert p.visits == ["E1", "X1", "E2", "E3"]
    assert plan("elbow-cross", route="B").visits == ["E3", "E2", "X1"]
    assert plan("elbow-cross", route="C").visits == ["E1", "X1"]
    for route in "ABC":
        q = plan("elbow-cross", route=route)
        assert scene.contains(q.trajectory.positions).all()


def test_rendered_bend_wall_and_texture_run_on_from_the_straight_piece(scene):
    cam = fisheye_camera(160, 120)
    r = Renderer(scene, cam, Appearance(mm_per_px=1.0, noise=False), seed=1)
    bend = next(b for b in scene.bends if b.id == "E2.arc")
    pipe = next(p for p in scene.pipes if p.id == "W.1")
    # camera on W.1's axis 0.3 m before the bend, looking along it
    u = pipe.axis
    origin = pipe.end - 0.3 * u
    z = u
    x = np.cross([0.0, 0.0, 1.0], z)
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z], axis=1)
    P, N, h, s, hits = r.surface_points(R, origin)
    world = origin + (R @ P.astype(float)).T
    kb = len(scene.pipes) + scene.bends.index(bend)
    on = hits.pipe == kb
    assert on.sum() > 200
    _, d = bend.tube_coordinates(world[on])
    assert np.abs(d - R_PIPE).max() < 2e-5  # float32 rendering: to 20 um at up to a metre
    # the inward normal points from the wall to the axis circle
    np.testing.assert_allclose(np.linalg.norm(N[:, on], axis=0), 1.0, atol=1e-4)
    # texture coordinates along the shared wall (chain W): neighbouring pixels across the seam between
    # W.1 and the bend differ as little as neighbours on one piece do
    kp = scene.pipes.index(pipe)
    H, W = cam.height, cam.width
    piece = np.full(H * W, -1)
    piece[r.pixels.index] = hits.pipe
    chain_h = np.zeros(H * W)
    chain_h[r.pixels.index] = h + np.array(r.h_offsets)[np.maximum(hits.pipe, 0)]
    ss = np.zeros(H * W)
    ss[r.pixels.index] = s
    piece, chain_h, ss = piece.reshape(H, W), chain_h.reshape(H, W), ss.reshape(H, W)
    across = (piece[:, :-1] == kp) & (piece[:, 1:] == kb) | (piece[:, :-1] == kb) & (piece[:, 1:] == kp)
    within = (piece[:, :-1] == kp) & (piece[:, 1:] == kp)
    assert across.sum() > 10
    dh = np.abs(np.diff(chain_h, axis=1))
    ds = np.abs(np.angle(np.exp(1j * np.diff(ss, axis=1) / R_PIPE))) * R_PIPE
    assert dh[across].max() < 3 * np.percentile(dh[within], 99) + 1e-3
    assert ds[across].max() < 3 * np.percentile(ds[within], 99) + 1e-3
