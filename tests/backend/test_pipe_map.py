"""PipeMap: a correction after a keyframe moves everything that hangs from the later poses, and nothing else."""

from __future__ import annotations

import numpy as np

from pipemap.backend.network_map import MappedJunction, MappedSection
from pipemap.backend.pipe_map import PipeMap
from pipemap.frontend.tracks import Keyframe
from pipemap.geometry.cylinder import Cylinder
from pipemap.geometry.rotations import exp_so3


def _keyframe(k: int, tracks) -> Keyframe:
    n = len(tracks)
    return Keyframe(k, k, float(k), np.zeros((n, 2)), np.tile([0.0, 0.0, 1.0], (n, 1)), np.asarray(tracks),
                    np.ones(n, bool), np.zeros(n, bool), np.eye(3), np.zeros(3), True)


def _map() -> PipeMap:
    """Six keyframes along x; tracks 0-1 first seen at keyframe 0, 2-3 at 2, 4-5 at 4 (listed out of order)."""
    keyframes = [_keyframe(k, t) for k, t in enumerate([[0, 1], [0, 1], [1, 2, 3], [2, 3], [3, 4, 5], [5, 4]])]
    poses = np.tile(np.eye(4), (6, 1, 1))
    poses[:, 0, 3] = 0.1 * np.arange(6)
    tracks = np.array([4, 0, 2, 5, 1, 3])
    points = np.column_stack([0.1 * tracks, np.full(6, 0.2), np.zeros(6)])
    sections = [MappedSection(0, 0, 1, Cylinder(np.zeros(3), np.array([1.0, 0, 0]), 0.2), None, None),
                MappedSection(1, 3, 5, Cylinder(np.array([0.0, 0.01, 0]), np.array([1.0, 0, 0]), 0.2), None, None,
                              bend=(np.array([0.0, 0.1]), np.array([[0.0, 0.001, 0], [0.0, 0.002, 0]])))]
    junctions = [MappedJunction("T1", np.array([0.2, 0, 0]), 2, 2, 2, 0, 1, 90.0, "axes"),
                 MappedJunction("E1", np.array([0.5, 0, 0]), 5, 5, 5, 1, None, 90.0, "elbow", type="elbow",
                                axes=np.array([[1.0, 0, 0], [0, 1.0, 0]]))]
    return PipeMap.build(keyframes, poses, points, tracks, sections, junctions)


def test_owners_are_the_first_keyframe_seeing_each_point():
    m = _map()
    assert m.owners.tolist() == [4, 0, 2, 4, 0, 2]


def test_move_after_moves_later_poses_points_sections_and_junctions_rigidly():
    m = _map()
    T = np.eye(4)
    T[:3, :3] = exp_so3(np.array([0.0, 0.0, 0.3]))
    T[:3, 3] = [0.05, -0.02, 0.01]
    moved = m.copy()
    moved.move_after(2, T)
    assert np.array_equal(moved.poses[:3], m.poses[:3])
    assert np.allclose(moved.poses[3:], T @ m.poses[3:])
    later = m.owners > 2
    assert np.allclose(moved.points[later], m.points[later] @ T[:3, :3].T + T[:3, 3])
    assert np.array_equal(moved.points[~later], m.points[~later])
    s0, s1 = moved.sections
    assert s0.cylinder.origin.tolist() == m.sections[0].cylinder.origin.tolist()
    assert np.allclose(s1.cylinder.direction, T[:3, :3] @ m.sections[1].cylinder.direction)
    assert np.allclose(s1.bend[1], m.sections[1].bend[1] @ T[:3, :3].T) and np.array_equal(s1.bend[0], [0.0, 0.1])
    assert np.isclose(s1.start_h, s1.cylinder.axial(moved.poses[3, :3, 3][None])[0])
    assert np.array_equal(moved.junctions[0].centroid, [0.2, 0, 0])
    assert np.allclose(moved.junctions[1].centroid, T[:3, :3] @ [0.5, 0, 0] + T[:3, 3])
    assert np.allclose(moved.junctions[1].axes, m.junctions[1].axes @ T[:3, :3].T)  # the elbow's solved axes
    # the map it was copied from is untouched
    assert np.array_equal(m.sections[1].cylinder.origin, [0.0, 0.01, 0]) and m.poses[5, 0, 3] == 0.5


def test_reanchor_moves_each_point_with_its_owner():
    m = _map()
    new = m.poses.copy()
    for k in range(6):  # a correction growing along the route, as loop closure gives
        new[k, :3, :3] = exp_so3(np.array([0.0, 0.02 * k, 0.0]))
        new[k, :3, 3] += [0.0, 0.003 * k, 0.0]
    out = m.copy()
    out.reanchor(new)
    for i, k in enumerate(m.owners):
        in_camera = np.linalg.inv(m.poses[k]) @ np.append(m.points[i], 1.0)
        assert np.allclose(out.points[i], (new[k] @ in_camera)[:3])
    j = m.junctions[1]
    assert np.allclose(out.junctions[1].centroid, (new[5] @ np.linalg.inv(m.poses[5]) @ np.append(j.centroid, 1))[:3])
    assert np.allclose(out.junctions[1].axes, j.axes @ new[5, :3, :3].T)  # turned with its keyframe
    assert np.array_equal(out.poses, new)
