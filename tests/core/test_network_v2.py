"""pipemap-network/2: junction types, elbows with their angle and bend radius, arc segments; /1 still read."""

import numpy as np
import pytest

from pipemap.errors import PipemapError
from pipemap.network import Junction, PipeNetwork, Segment, load_network, save_network

R_BEND = 0.45


def _elbow_network() -> PipeNetwork:
    """S1 along +x to the arc's start, a 90 deg elbow about +z at bend radius 0.45, S2 along +y; a cross beyond."""
    arc = Segment("E1.arc", np.array([1.55, 0, 0]), np.array([2.0, R_BEND, 0]), np.array([1.55, R_BEND, 0]), "E1")
    segs = (Segment("S1", np.zeros(3), arc.start), arc, Segment("S2", arc.end, np.array([2.0, 2.0, 0])))
    junctions = (Junction("E1", "elbow", np.array([2.0, 0, 0]), 90.0, R_BEND),
                 Junction("X1", "cross", np.array([2.0, 2.0, 0])))
    return PipeNetwork(0.15, segs, junctions, ("E1", "X1"))


def test_arc_geometry_follows_the_circle():
    arc = _elbow_network().segments[1]
    assert arc.kind == "arc" and arc.bend_radius == pytest.approx(R_BEND, abs=1e-12)
    assert np.degrees(arc.angle) == pytest.approx(90.0, abs=1e-10)
    # chainage along an elbow is the arc's length, bend radius x angle, not the chord
    assert arc.length == pytest.approx(R_BEND * np.pi / 2, abs=1e-12)
    h = np.linspace(0, arc.length, 50)
    pos, tan = arc.axis_points(h)
    np.testing.assert_allclose(np.linalg.norm(pos - arc.centre, axis=1), R_BEND, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(tan, axis=1), 1.0, atol=1e-12)
    # the tangent is the derivative of the position with respect to chainage (central differences, 1e-7 m)
    d = 1e-7
    numeric = (arc.axis_points(h + d)[0] - arc.axis_points(h - d)[0]) / (2 * d)
    np.testing.assert_allclose(numeric, tan, atol=1e-7)
    np.testing.assert_allclose(pos[[0, -1]], [arc.start, arc.end], atol=1e-12)
    t0, t1 = arc.tangents
    np.testing.assert_allclose(t0, [1, 0, 0], atol=1e-12)  # joins S1 tangentially ...
    np.testing.assert_allclose(t1, [0, 1, 0], atol=1e-12)  # ... and S2
    np.testing.assert_allclose(arc.vertex, [2.0, 0, 0], atol=1e-12)  # where the straight axes meet
    with pytest.raises(ValueError, match="arc"):
        _ = arc.axis


def test_version_2_round_trip(tmp_path):
    net = _elbow_network()
    save_network(tmp_path / "n.yaml", net)
    text = (tmp_path / "n.yaml").read_text()
    assert text.startswith("format: pipemap-network/2") and "kind: arc" in text and "type: cross" in text
    back = load_network(tmp_path / "n.yaml")
    assert [s.kind for s in back.segments] == ["line", "arc", "line"] and back.segments[1].junction == "E1"
    e1 = back.junction("E1")
    assert (e1.type, e1.angle_deg, e1.bend_radius_m) == ("elbow", 90.0, R_BEND)
    assert back.junction("X1").type == "cross" and back.visits == ("E1", "X1")
    np.testing.assert_allclose(back.segments[1].centre, [1.55, R_BEND, 0], atol=0)
    assert sum(s.length for s in back.segments) == pytest.approx(1.55 + R_BEND * np.pi / 2 + 2.0 - R_BEND, abs=1e-12)


def test_version_1_still_reads(tmp_path):
    (tmp_path / "n.yaml").write_text("format: pipemap-network/1\nradius_m: 0.2\nsegments:\n"
                                     "  - {id: S1, start: [0, 0, 0], end: [8.15, 0, 0]}\n"
                                     "junctions:\n  - {id: T1, centroid: [8.15, 0, 0]}\nvisits: [T1]\n")
    net = load_network(tmp_path / "n.yaml")
    assert net.junction("T1").type == "tee" and net.segments[0].length == pytest.approx(8.15)


@pytest.mark.parametrize("edit, message", [
    (("format: pipemap-network/2", "format: pipemap-network/3"), r"format: expected 'pipemap-network/2'"),
    (("type: cross", "type: wye"), r"junctions\[1\]\.type: unknown junction type 'wye'"),
    (("0.0]\n  angle_deg: 90.0\n", "0.0]\n"), r"junctions\[0\]\.angle_deg: an elbow needs"),
    (("kind: arc", "kind: spline"), r"segments\[1\]\.kind: unknown segment kind 'spline'"),
    (("centre: [1.55, 0.45, 0.0]", "centre: [1.55, 0.5, 0.0]"), r"segments\[1\]: start and end must lie at one"),
    (("angle_deg: 90.0\n  junction", "angle_deg: 80.0\n  junction"), r"segments\[1\]\.angle_deg: 80.0 disagrees"),
    (("junction: E1", "junction: X1"), r"segments\[1\]\.junction: 'X1' names no elbow"),
    (("centroid: [2.0, 0.0, 0.0]", "centroid: [2.0, 0.1, 0.0]"),
     r"segments\[1\]\.junction: arc E1\.arc disagrees with elbow E1"),
    (("format: pipemap-network/2", "format: pipemap-network/1"), r"segments\[1\]\.kind: arc segments need"),
])
def test_bad_version_2_files_are_one_line_errors(tmp_path, edit, message):
    save_network(tmp_path / "n.yaml", _elbow_network())
    text = (tmp_path / "n.yaml").read_text()
    assert edit[0] in text, text
    (tmp_path / "n.yaml").write_text(text.replace(edit[0], edit[1], 1))
    with pytest.raises(PipemapError, match="n.yaml: " + message):
        load_network(tmp_path / "n.yaml")
