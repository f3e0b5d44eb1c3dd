"""Loop edges from a tee passed twice: both passes measured the same tee frame."""

import numpy as np

from pipemap.backend.junction_loops import junction_identity_edges, tee_frame
from pipemap.backend.network_map import MappedJunction, MappedSection
from pipemap.backend.pipe_map import PipeMap
from pipemap.config import LoopClosureSettings
from pipemap.geometry.cylinder import Cylinder
from pipemap.geometry.rotations import exp_so3

R = 0.15


def _pose(rotvec, t):
    T = np.eye(4)
    T[:3, :3] = exp_so3(np.asarray(rotvec, float))
    T[:3, 3] = t
    return T


def _map(drift: np.ndarray) -> PipeMap:
    """A tee at the origin (through pipe along x, branch along +y). Keyframe 1 passes it straight through
    along +x; keyframe 4 comes back down the branch (-y) and turns into the through pipe towards -x. The
    second visit's poses, sections and pass carry `drift` (4, 4, world -> world), as odometry would."""
    poses = np.stack([_pose([0, 0, 0], [x, 0, 0]) for x in (-0.6, 0.0, 0.6)]
                     + [_pose([0, 0, 0], [0, y, 0]) for y in (0.6, 0.0)] + [_pose([0, 0, 0], [-0.6, 0, 0])])
    poses[3:] = drift @ poses[3:]
    Rd, td = drift[:3, :3], drift[:3, 3]
    x, y = np.array([1.0, 0, 0]), np.array([0, 1.0, 0])
    sections = [MappedSection(0, 0, 0, None, None, Cylinder([-0.6, 0, 0], x, R)),
                MappedSection(2, 2, 2, None, Cylinder([0.6, 0, 0], x, R), None),
                MappedSection(4, 3, 3, None, None, Cylinder(Rd @ [0, 0.6, 0] + td, Rd @ -y, R)),
                MappedSection(6, 5, 5, None, Cylinder(Rd @ [-0.6, 0, 0] + td, Rd @ -x, R), None)]
    passes = [MappedJunction("T1", np.zeros(3), 1, 1, 1, 0, 2, 0.1, "side-opening", branch=y.copy()),
              MappedJunction("T2", td.copy(), 4, 4, 4, 4, 6, 90.0, "tee-model", through="blue")]
    return PipeMap([], poses, np.zeros((0, 3)), np.zeros(0, np.int64), np.zeros(0, np.int64), sections, passes)


def test_both_passes_give_the_same_frame_without_drift():
    m = _map(np.eye(4))
    F1, F2 = tee_frame(m, m.junctions[0]), tee_frame(m, m.junctions[1])
    np.testing.assert_allclose(F1[:3, 0], [0, 1, 0], atol=1e-12)  # x along the branch
    np.testing.assert_allclose(abs(F1[:3, 2] @ F2[:3, 2]), 1.0, atol=1e-12)  # one through axis, either way
    np.testing.assert_allclose(F2[:3, 0], [0, 1, 0], atol=1e-12)
    edges = junction_identity_edges(m, R, LoopClosureSettings())
    assert len(edges) == 1 and (edges[0].i, edges[0].j) == (1, 4)
    np.testing.assert_allclose(edges[0].T_ij, np.linalg.inv(m.poses[1]) @ m.poses[4], atol=1e-12)


def test_edge_measures_the_undrifted_relative_pose():
    drift = _pose([0.0, 0.0, np.radians(1.0)], [0.02, -0.01, 0.005])
    m, truth = _map(drift), _map(np.eye(4))
    edges = junction_identity_edges(m, R, LoopClosureSettings())
    assert len(edges) == 1
    np.testing.assert_allclose(edges[0].T_ij, np.linalg.inv(truth.poses[1]) @ truth.poses[4], atol=1e-9)


def test_no_edge_when_the_passes_disagree():
    m = _map(np.eye(4))
    m.junctions[0].branch = np.array([0, 0, 1.0])  # the opening found on another side: not the same branch
    assert junction_identity_edges(m, R, LoopClosureSettings()) == []
