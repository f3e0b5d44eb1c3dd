"""The route's chainage and clock against the network's own arc-length maths, the up estimate, the wall cast,
observations' clock arcs and the plan similarity of the exports."""

from __future__ import annotations

import numpy as np
import pytest

from pipemap.errors import PipemapError
from pipemap.inspection.export import network_geojson, plan_similarity, sections_csv
from pipemap.inspection.network_route import legs_and_joints
from pipemap.inspection.observations import clock_arc
from pipemap.inspection.route import Route
from pipemap.inspection.route_build import Joint, Leg, build_route
from pipemap.inspection.up import estimate_up
from pipemap.inspection.wall_cast import cast_to_wall, wall_shapes
from pipemap.network import Segment

R = 0.15
UP = np.array([0.0, 0.0, 1.0])


def elbow_route() -> tuple[Route, Segment]:
    """1.55 m along +x, a 90 deg elbow of bend radius 0.45 about (1.55, 0.45), then 1 m along +y."""
    legs = [Leg("S0", np.array([0.0, 0, 0]), np.array([1.55, 0, 0])),
            Leg("S2", np.array([2.0, 0.45, 0]), np.array([2.0, 1.45, 0]))]
    route = build_route(legs, [Joint("E1", "elbow", None, 0.45)], np.array([0.2, 0.0, -0.04]),
                        np.array([2.0, 1.3, -0.04]), UP, R, {"method": "test"})
    arc = Segment("E1.arc", np.array([1.55, 0, 0]), np.array([2.0, 0.45, 0]), np.array([1.55, 0.45, 0]))
    return route, arc


def test_chainage_follows_the_arc_as_the_network_measures_it():
    route, arc = elbow_route()
    assert [s.kind for s in route.segments] == ["line", "arc", "line"]
    assert route.segments[1].chainage_start == pytest.approx(1.35, abs=1e-9)  # from the first camera at x = 0.2
    assert route.length == pytest.approx(1.35 + arc.length + 0.85, abs=1e-9)
    h = np.linspace(0.0, arc.length, 7)
    axis, tangent = arc.axis_points(h)
    normal = np.cross(tangent, UP)  # 9 o'clock looking along the tangent: left of travel
    c, k, rho, seg = route.to_route(axis - R * normal, wall=True)
    np.testing.assert_allclose(c, 1.35 + h, atol=1e-9)
    np.testing.assert_allclose(k, 270.0, atol=1e-6)
    np.testing.assert_allclose(rho, R, atol=1e-9)
    assert (seg[1:] == 1).all()  # the arc's first point is also the line's last, at the same chainage
    assert route.nodes[0][0] == "E1" and route.nodes[0][2] == pytest.approx(1.35 + arc.length / 2)


def test_clock_convention_and_round_trip():
    route, _ = elbow_route()
    # looking along +x with z up: 12 o'clock is +z, 3 o'clock is -y (the right hand side)
    c, k, _, _ = route.to_route([[1.0, 0, R], [1.0, -R, 0], [1.0, 0, -R], [1.0, R, 0]])
    np.testing.assert_allclose(k, [0, 90, 180, 270], atol=1e-9)
    rng = np.random.default_rng(0)
    chain = rng.uniform(0.0, route.length, 50)
    clock = rng.uniform(0.0, 360.0, 50)
    back = route.to_route(route.from_route(chain, clock), wall=True)
    np.testing.assert_allclose(back[0], chain, atol=1e-9)
    np.testing.assert_allclose((back[1] - clock + 180) % 360 - 180, 0.0, atol=1e-7)


def test_points_taken_in_parts_and_by_their_known_segment_locate_as_all_at_once(monkeypatch):
    """Map points go through to_route a part at a time (memory) and, where their wall piece is known, on that
    segment alone: the same coordinates as every segment's candidates of all points at once."""
    import pipemap.inspection.route as route_module

    route, _ = elbow_route()
    rng = np.random.default_rng(2)
    points = route.from_route(rng.uniform(0.0, route.length, 500), rng.uniform(0.0, 360.0, 500))
    points += rng.normal(0.0, 0.003, points.shape)
    whole = route.to_route(points, wall=True)
    near = whole[0] + rng.uniform(-0.2, 0.2, 500)
    whole_near = route.to_route(points, wall=True, near_chainage=near)
    monkeypatch.setattr(route_module, "POINTS_AT_ONCE", 64)
    for got, want in zip(route.to_route(points, wall=True), whole):
        np.testing.assert_array_equal(got, want)
    for got, want in zip(route.to_route(points, wall=True, near_chainage=near), whole_near):
        np.testing.assert_array_equal(got, want)
    for got, want in zip(route.to_route(points, wall=True, segment=whole[3]), whole):
        np.testing.assert_allclose(got, want, atol=1e-12)


def test_up_from_image_up_and_camera_side():
    rng = np.random.default_rng(1)
    n = 40
    centres = np.column_stack([np.linspace(0, 1.5, n), np.zeros(n), np.full(n, -0.04)])
    roll = np.radians(rng.normal(0.0, 0.5, n))
    rots = []
    for a in roll:  # camera looks along +x, image down (y) = -z turned by the roll about x
        y = -np.array([0.0, -np.sin(a), np.cos(a)])
        rots.append(np.column_stack([np.cross(y, [1.0, 0, 0]), y, [1.0, 0, 0]]))
    up, record = estimate_up(np.array(rots), centres, np.array([[0.0, 0, 0]]), np.array([[1.5, 0, 0]]), R)
    assert np.degrees(np.arccos(up @ UP)) < 0.3  # the mean of 40 rolls of 0.5 deg
    assert record["camera_side_vs_image_deg"] < 0.3 and record["roll_spread_deg"] == pytest.approx(0.5, abs=0.2)
    with pytest.raises(PipemapError):
        estimate_up(np.array(rots), centres * [1, 1, 0], np.array([[0.0, 0, 0]]), np.array([[1.5, 0, 0]]), R,
                    "camera-side")


def test_wall_cast_meets_the_tube_and_the_bend():
    route, arc = elbow_route()
    pieces = [{"name": "S0", "start": [0.0, 0, 0], "end": [1.55, 0, 0], "radius": R},
              {"name": "S2", "start": [2.0, 0.45, 0], "end": [2.0, 1.45, 0], "radius": R}]
    tubes, bends = wall_shapes(pieces, route)
    origin = np.array([0.5, 0.0, -0.04])
    dirs = np.array([[0.0, 0, 1], [0.0, -1, 0], [1.0, 0, 0]])
    p, ok, shape = cast_to_wall(origin, dirs, tubes, bends)
    assert ok.all() and shape.tolist() == [0, 0, 2]
    np.testing.assert_allclose(p[0], [0.5, 0, R], atol=1e-9)
    np.testing.assert_allclose(p[1], [0.5, -np.sqrt(R**2 - 0.04**2), -0.04], atol=1e-9)
    # straight ahead the ray meets the outside of the bend: on the torus wall
    q = p[2] - arc.centre
    assert np.hypot(np.hypot(q[0], q[1]) - 0.45, q[2]) == pytest.approx(R, abs=1e-7)


def test_clock_arc_and_plan_similarity():
    assert clock_arc(np.array([350.0, 10.0, 0.0])) == (350.0, 10.0)
    assert clock_arc(np.array([80.0, 100.0])) == (80.0, 100.0)
    A, b, scale = plan_similarity([0, 0], [10, 0], [100, 200], [100, 210])
    np.testing.assert_allclose(A @ [10, 0] + b, [100, 210], atol=1e-9)
    assert scale == pytest.approx(1.0)
    route, _ = elbow_route()
    doc = network_geojson(route)
    starts = [f for f in doc["features"] if f["properties"].get("id") == "start"]
    np.testing.assert_allclose(starts[0]["geometry"]["coordinates"], [0, 0, 0], atol=1e-9)
    rows = sections_csv(route).splitlines()
    assert rows[1].startswith("S0,line,start,E1,0.000,")
    assert rows[2].startswith("E1,arc,E1,E1,1.350,")  # an elbow's arc lies inside the elbow
    assert rows[3].startswith("S2,line,E1,end,")
    assert "crs" not in doc and "not WGS84" in doc["properties"]["crs"]


def test_georeferenced_geojson_names_its_coordinate_system():
    route, _ = elbow_route()
    end = route.from_route(route.length, 0.0, 0.0)[0]
    start = route.from_route(0.0, 0.0, 0.0)[0]
    plan = float(np.hypot(*(end - start)[:2]))
    doc = network_geojson(route, [500000.0, 180000.0], [500000.0, 180000.0 + plan], "EPSG:27700")
    assert doc["crs"] == {"type": "name", "properties": {"name": "urn:ogc:def:crs:EPSG::27700"}}
    assert doc["properties"]["scale"] == pytest.approx(1.0, abs=1e-9)
    nodes = {f["properties"]["id"]: f["geometry"]["coordinates"] for f in doc["features"]
             if f["properties"]["kind"] == "node"}
    np.testing.assert_allclose(nodes["end"][:2], [500000.0, 180000.0 + plan], atol=1e-4)
    with pytest.raises(PipemapError, match="EPSG"):
        network_geojson(route, [0.0, 0.0], [0.0, plan], "British grid")
    with pytest.raises(PipemapError, match="--start-manhole"):
        network_geojson(route, crs="EPSG:27700")


def test_an_elbow_with_solved_axes_takes_its_arc_from_them():
    """The pass's `axes` (run.json junction_passes) and vertex place the arc exactly; the leg before, the
    straight section's own axis 0.5 deg off, ends at the projection of the arc's start."""
    tilt = np.radians(0.5)
    pieces = [{"name": "S0", "start": [0.0, 0.0, 0.0], "end": [1.55, 1.55 * np.tan(tilt), 0.0]},
              {"name": "S2", "start": [2.0, 0.45, 0.0], "end": [2.0, 1.45, 0.0]}]
    sections = [{"section": 0, "first_keyframe": 0, "last_keyframe": 9},
                {"section": 2, "first_keyframe": 20, "last_keyframe": 29}]
    elbow = {"id": "E1", "type": "elbow", "centroid": [2.0, 0.0, 0.0], "bend_radius_m": 0.45,
             "axes": [[2.0, 0.0, 0.0], [0.0, 1.0, 0.0]], "first_keyframe": 10, "last_keyframe": 19}
    legs, joints = legs_and_joints(pieces, sections, [elbow])
    route = build_route(legs, joints, np.zeros(3), np.array([2.0, 1.45, 0]), UP, R, {"method": "test"})
    line, arc, _ = route.segments
    np.testing.assert_allclose(arc.centre, [1.55, 0.45, 0.0], atol=1e-12)
    np.testing.assert_allclose([arc.start, arc.end], [[1.55, 0, 0], [2.0, 0.45, 0]], atol=1e-12)
    assert np.degrees(arc.angle) == pytest.approx(90.0, abs=1e-9)
    np.testing.assert_allclose(line.end, legs[0].project(arc.start), atol=1e-12)
    assert line.chainage_end == arc.chainage_start
    with pytest.raises(PipemapError, match="run.json: junction_passes E1: axes must be two non-zero 3-vectors"):
        legs_and_joints(pieces, sections, [dict(elbow, axes=[[1.0, 0.0, 0.0]])])


def test_a_crawler_that_reverses_out_keeps_its_pipe_in_the_route_and_the_wall_pieces():
    """A crawler that drives 4.5 m in and reverses out ends where it began: the section's wall and the route still
    run from the first camera to where it turned back (before, the wall piece was dropped as too short and a
    route ending behind its start had no segment)."""
    from pipemap.backend.network_map import camera_extent
    from pipemap.inspection.network_route import network_route

    out = np.linspace(0.0, 4.5, 46)
    h = np.concatenate([out, out[::-1][1:] - 0.02])  # back 2 cm behind the start
    assert camera_extent(h) == (0.0, 4.5)
    assert camera_extent(np.linspace(3.0, 1.0, 21)) == (3.0, 1.0)  # driven the other way along the axis
    assert camera_extent(np.array([0.0, -0.001, 1.0, 2.0])) == (0.0, 2.0)

    poses = np.tile(np.eye(4), (len(h), 1, 1))
    poses[:, 2, 3] = h
    pieces = [{"name": "S0", "start": [0.0, 0.0, 0.0], "end": [0.0, 0.0, 4.5], "radius": 0.2, "up": [0, -1, 0]}]
    sections = [{"section": 0, "first_keyframe": 0, "last_keyframe": len(h) - 1}]
    route = network_route(pieces, sections, [], poses, 0.2, up_choice=[0.0, -1.0, 0.0])
    assert len(route.segments) == 1
    assert route.segments[0].chainage_end == pytest.approx(4.5, abs=1e-9)
    # cameras that cover none of the pipe's length give no route, not a route without a segment
    still = np.tile(np.eye(4), (3, 1, 1))
    assert network_route(pieces, [dict(sections[0], last_keyframe=2)], [], still, 0.2, up_choice=[0.0, -1.0, 0.0]) \
        is None
