"""Elbow wall pieces: the arc from the straight axes, its grid on the true torus, sight through and around the
bend against exact ray casting, and the appearance map of a rendered elbow against the simulator's texture."""

from __future__ import annotations

import json

import numpy as np
import pytest
from mapping_helpers import high_pass

from pipemap.config import AppearanceSettings
from pipemap.dataset import load_dataset
from pipemap.errors import PipemapError
from pipemap.evaluation.wall_error import wall_distance
from pipemap.inspection.route_build import Joint, Leg, build_route
from pipemap.inspection.wall_cast import cast_to_wall, wall_shapes
from pipemap.mapping import ElbowPiece, WallPiece, build_appearance, piece_from_dict, wall_grid, with_elbows
from pipemap.mapping.unrolled import unrolled_image
from pipemap.mapping.wall import in_line_of_sight
from pipemap.network import PipeNetwork, Segment
from pipemap.sim.simulate import plan, simulate
from pipemap.sim.texture import WallTexture

R = 0.15
UP = np.array([0.0, 0.0, 1.0])
# elbow-cross's E1: vertex (2, 0, 0), 90 deg, bend radius 0.45 m; the legs as a map gives them (not at the arc)
LEGS = [Leg("S0", np.array([0.0, 0, 0]), np.array([1.6, 0, 0])),
        Leg("S2", np.array([2.0, 0.4, 0]), np.array([2.0, 1.6, 0]))]
TRUTH = PipeNetwork(R, (Segment("M1.1", np.array([0.0, 0, 0]), np.array([1.55, 0, 0])),
                        Segment("M1.2", np.array([2.0, 0.45, 0]), np.array([2.0, 1.6, 0])),
                        Segment("E1.arc", np.array([1.55, 0, 0]), np.array([2.0, 0.45, 0]), np.array([1.55, 0.45, 0]),
                                "E1")))


def elbow_route():
    return build_route(LEGS, [Joint("E1", "elbow", None, 0.45)], np.array([0.1, 0, 0]), np.array([2.0, 1.5, 0]),
                       UP, R, {})


def elbow_pieces() -> list:
    pieces = [{"name": leg.name, "start": leg.start.tolist(), "end": leg.end.tolist(), "radius": R,
               "up": UP.tolist(), "unroll": True} for leg in LEGS]
    return [piece_from_dict(d) for d in with_elbows(pieces, elbow_route())]


def test_the_elbow_piece_follows_the_true_arc_and_the_straight_pieces_meet_it():
    s0, e1, s2 = elbow_pieces()
    assert [p.kind for p in (s0, e1, s2)] == ["line", "arc", "line"]
    np.testing.assert_allclose(s0.end, [1.55, 0, 0], atol=1e-9)  # moved from 1.6 to the tangent point
    np.testing.assert_allclose(s2.start, [2.0, 0.45, 0], atol=1e-9)
    np.testing.assert_allclose(e1.end, s2.start, atol=1e-9)
    assert e1.length == pytest.approx(0.45 * np.pi / 2, abs=1e-9)
    grid = wall_grid(e1, 0.004)
    P = grid.points()
    assert np.max(wall_distance(P.reshape(-1, 3), TRUTH)) < 1e-9  # on the exact torus
    # the outside of the bend is sampled as finely as a straight piece: rows closer along the axis
    assert grid.spacing_h * (0.45 + R) / 0.45 == pytest.approx(0.004, rel=0.02)
    h, phi, rho = e1.wall_coordinates(P)
    np.testing.assert_allclose(h, np.broadcast_to(grid.h[:, None], h.shape), atol=1e-9)
    np.testing.assert_allclose(np.cos(phi), np.cos(np.broadcast_to(grid.phi, phi.shape)), atol=1e-9)
    np.testing.assert_allclose(rho, R, atol=1e-9)
    # phi = pi / 2 is 3 o'clock, looking along the arc: at its start (heading +x, up +z) that is -y, the inside
    np.testing.assert_allclose(e1.wall_points([0.0], [np.pi / 2])[0, 0], [1.55, -R, 0], atol=1e-9)
    again = piece_from_dict(json.loads(json.dumps(e1.to_dict())))
    assert again.name == "E1" and again.angle_deg == pytest.approx(90.0, abs=1e-6)
    np.testing.assert_allclose(again.wall_points(grid.h[::50], grid.phi[::50]), P[::50, ::50], atol=1e-6)


@pytest.mark.parametrize("change, message", [({"angle_deg": 180.0}, "less than 180"),
                                             ({"kind": "spiral"}, "unknown kind"),
                                             ({"up": [0.0, 1.0, 0.0]}, "12 o'clock is undefined"),
                                             ({"centre": [1.55, 0.1, 0.0]}, "farther from the centre")])
def test_a_bad_elbow_record_is_one_clear_error(change, message):
    d = dict(elbow_pieces()[1].to_dict(), **change)
    with pytest.raises(PipemapError, match=message):
        piece_from_dict(d, "run.json: wall_pieces[1]")


def test_line_of_sight_through_and_around_the_bend_matches_exact_ray_casting():
    """Seen from the straight pipe before the elbow, from inside the bend and from the pipe after it: a wall point
    is in sight exactly when the camera's ray meets the wall there first (ray casting onto the cylinders and the
    exact torus). Without the elbow piece the bend's wall and the pipe beyond would be out of sight."""
    pieces = elbow_pieces()
    tubes, bends = wall_shapes([p.to_dict() for p in pieces], elbow_route())
    rng = np.random.default_rng(1)
    P = np.concatenate([wall_grid(p, 0.01).points().reshape(-1, 3) for p in pieces])
    P = P[rng.choice(len(P), 4000, replace=False)]
    for c in ([1.2, 0.02, -0.05], [1.62, -0.05, -0.04], [1.85, 0.2, 0.03], [2.03, 0.8, -0.04]):
        c = np.array(c)
        fast = in_line_of_sight(c, P, pieces, 1e-5)
        d = P - c
        hit, ok, _ = cast_to_wall(c, d / np.linalg.norm(d, axis=1, keepdims=True), tubes, bends)
        exact = ok & (np.linalg.norm(hit - P, axis=1) < 2e-3)  # a grazing ray's hit may fall that far off
        assert fast.any() and (~fast).any()
        assert np.mean(fast == exact) > 0.995, c


@pytest.fixture(scope="session")
def elbow_case(tmp_path_factory):
    """elbow-cross A through E1: 70 frames 3 cm apart at 320 x 240, mapped at the true poses with the true pieces."""
    kw = dict(width=320, height=240, frames=70, seed=0, spacing_m=0.03, route="A")
    root = simulate("elbow-cross", tmp_path_factory.mktemp("elbow") / "data", **kw)
    ds = load_dataset(root)
    scene = plan("elbow-cross", **kw).setup.scene
    bend = next(b for b in scene.bends if b.id == "E1.arc")
    net = ds.network()
    pieces = [WallPiece(s.id, s.start, s.end, R, bend.up) for s in net.segments if s.id in ("M1.1", "M1.2")]
    elbow = ElbowPiece("E1", bend.centre + bend.bend_radius * bend.e1, bend.centre, bend.normal,
                       np.degrees(bend.angle), R, bend.up)
    gt = ds.ground_truth_poses()
    T = gt.matrices()
    maps = [build_appearance(ds, np.arange(len(gt)), poses, [pieces[0], elbow, pieces[1]], AppearanceSettings())
            for poses in (T, _shifted(T, 0.03))]
    look = plan("elbow-cross", **kw).setup.appearance
    texture = WallTexture(kw["seed"], look.mm_per_px, look.texture_style)
    return maps, bend, texture, net


def _shifted(T: np.ndarray, metres: float) -> np.ndarray:
    """The poses moved `metres` further along the path."""
    out = T.copy()
    tangent = np.gradient(T[:, :3, 3], axis=0)
    out[:, :3, 3] += metres * tangent / np.linalg.norm(tangent, axis=1, keepdims=True)
    return out


def _texture_correlation(pm, bend, texture) -> float:
    key, h0, total = bend.chain  # the run's texture goes on unbroken into the bend, h along its axis
    surf = texture.surface(key, total, 2 * np.pi * R)
    hh, ph = np.meshgrid(pm.grid.h, pm.grid.phi, indexing="ij")
    albedo = surf.sample(h0 + hh, -ph * R, 0.004)  # the simulator's s runs anticlockwise, phi clockwise
    seen = pm.seen
    return float(np.corrcoef(high_pass(pm.intensity, seen)[seen], high_pass(albedo, seen)[seen])[0, 1])


def test_the_elbow_map_lies_on_the_true_wall_and_follows_its_texture(elbow_case):
    """The bend's map at the true poses: every point on the exact torus, the grey levels those of the simulator's
    wall texture there (0.56 measured: the straight pieces beside it 0.67-0.74, the bend's wall seen more
    obliquely), and not with the poses 3 cm off (-0.01 measured)."""
    (amap, shifted), bend, texture, net = elbow_case
    pm = amap.piece("E1")
    assert pm.seen.mean() > 0.9
    assert np.max(wall_distance(pm.grid.points()[pm.seen], net)) < 1e-6
    good = _texture_correlation(pm, bend, texture)
    assert good > 0.45
    assert _texture_correlation(shifted.piece("E1"), bend, texture) < 0.2 * good
    img, meta = unrolled_image(pm, 0.004, 1.55)
    assert meta["format"] == "pipemap-unrolled/3" and meta["axis"]["kind"] == "arc"
    assert img.shape == (round(2 * np.pi * R / 0.004), round(0.45 * np.pi / 2 / 0.004) + 1)
    assert meta["metres_per_pixel_along"] * (img.shape[1] - 1) == pytest.approx(0.45 * np.pi / 2, abs=1e-9)
