"""Loop closure on the demo-loop preset's route B, which drives around the loop and on along the
first two sides again: candidate pairs from the revisited sections, the metric relative pose of
two rendered frames of one place, and the whole chain correcting drifted odometry."""

from __future__ import annotations

import numpy as np
import pytest

from pipemap.backend.loop_closure import (StraightSection, TeeJunction, close_loops, cylinder_in_camera,
                                          loop_candidates, reanchor, same_pipe)
from pipemap.backend.place_match import _TwoWayProblem, match_sift, relative_pose
from pipemap.backend.pose_graph import relative_poses
from pipemap.config import LoopClosureSettings, Settings
from pipemap.dataset import load_dataset
from pipemap.geometry.cylinder import Cylinder
from pipemap.geometry.rotations import exp_so3, rotation_angle
from pipemap.geometry.se3 import as_rt, compose, invert, to_matrix, world_to_camera
from pipemap.network import load_network
from pipemap.sim.simulate import plan, simulate
from pipemap.trajectory import read_tum

RADIUS = 0.2
ROUTE = dict(width=320, height=240, route="B", seed=0)
TEE_MARGIN_M = 0.25  # frames this close to a tee centroid belong to the junction, not a straight section


# -- a map of the route built from ground truth, in the frame of drifted odometry ---------------------


def drift(T: np.ndarray, yaw_deg_per_m: float = 0.6, scale: float = 0.01, seed: int = 0) -> np.ndarray:
    """Odometry with a heading bias, a scale error and a little noise, integrated from the true first pose."""
    rng = np.random.default_rng(seed)
    R, t = as_rt(relative_poses(T))
    L = np.linalg.norm(t, axis=1)
    phi = np.radians(yaw_deg_per_m) * L[:, None] * np.array([0.0, -1.0, 0.0])  # camera y is down
    phi += rng.normal(scale=np.radians(0.02), size=phi.shape) * np.sqrt(L)[:, None]
    Rs, ts = R @ exp_so3(phi), t * (1.0 + scale)
    out_R, out_t = [T[0, :3, :3]], [T[0, :3, 3]]
    for r, p in zip(Rs, ts):
        a, b = compose(out_R[-1], out_t[-1], r, p)
        out_R.append(a)
        out_t.append(b)
    return to_matrix(np.array(out_R), np.array(out_t))


def side_axes(network) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Each side of the loop (segments S<k>.*) as one straight axis (start, end)."""
    sides: dict[str, list] = {}
    for seg in network.segments:
        if seg.id.startswith("S"):
            sides.setdefault(seg.id.split(".")[0], []).append(seg)
    return {k: (v[0].start, v[-1].end) for k, v in sides.items()}


def route_map(true_T: np.ndarray, odometry_T: np.ndarray, network):
    """Straight sections and tee passes of the route, placed in the odometry's (drifted) frame the way a
    mapping run would have them: each section's axis and each tee moved with a pose it was seen from."""
    P = true_T[:, :3, 3]
    axes = side_axes(network)
    names = list(axes)

    def dist_to(a, b):
        d = (b - a) / np.linalg.norm(b - a)
        h = np.clip((P - a) @ d, 0, np.linalg.norm(b - a))
        return np.linalg.norm(P - a - h[:, None] * d, axis=1)

    side = np.argmin(np.stack([dist_to(*axes[k]) for k in names]), axis=0)
    tees = np.stack([j.centroid for j in network.junctions])
    near_tee = np.min(np.linalg.norm(P[:, None] - tees[None], axis=-1), axis=1) < TEE_MARGIN_M
    label = np.where(near_tee, -1, side)
    starts = [k for k in range(len(P)) if label[k] >= 0 and (k == 0 or label[k - 1] != label[k])]
    sections, true_sides = [], []
    for first in starts:
        last = first
        while last + 1 < len(P) and label[last + 1] == label[first]:
            last += 1
        mid = (first + last) // 2
        a, b = reanchor(np.stack(axes[names[label[first]]]), true_T[mid], odometry_T[mid])
        sections.append(StraightSection(first, last, a, b - a))
        true_sides.append(names[label[first]])
    junctions = []
    for n in range(len(sections) - 1):
        gap = np.arange(sections[n].last + 1, sections[n + 1].first)
        k = gap[np.argmin(np.min(np.linalg.norm(P[gap, None] - tees[None], axis=-1), axis=1))]
        tee = tees[np.argmin(np.linalg.norm(tees - P[k], axis=1))]
        junctions.append(TeeJunction(reanchor(tee, true_T[k], odometry_T[k]), (n, n + 1)))
    return sections, junctions, true_sides


@pytest.fixture(scope="module")
def route():
    """The paper-loop network's route B (no images): 33 m around, then 1.5 m along two sides again."""
    p = plan("paper-loop", spacing_m=0.05, **ROUTE)
    network = p.setup.scene.network(p.visits)
    T = p.trajectory.matrices()
    D = drift(T, yaw_deg_per_m=0.03)
    sections, junctions, sides = route_map(T, D, network)
    return T, D, sections, junctions, sides


@pytest.fixture(scope="module")
def revisit(tmp_path_factory):
    """demo-loop route B at 320 x 240, a frame every 5 cm (165 frames)."""
    return simulate("demo-loop", tmp_path_factory.mktemp("loop") / "b", spacing_m=0.05, **ROUTE)


# -- candidates ---------------------------------------------------------------------------------------


def test_candidates_pair_the_revisited_sections_only(route):
    T, D, sections, junctions, sides = route
    assert sides == ["S4", "S3", "S2", "S1", "S4", "S3"]  # route B: the first two sides are driven twice
    drift_at_revisit = np.linalg.norm(D[sections[4].first, :3, 3] - T[sections[4].first, :3, 3])
    assert 0.05 < drift_at_revisit < RADIUS  # enough drift to matter, less than the test's tolerance
    settings = LoopClosureSettings(candidates_per_section=6)
    cands = loop_candidates(sections, junctions, D, RADIUS, settings)
    assert {(c.section_i, c.section_j) for c in cands} == {(0, 4), (1, 5)}
    for pair in [(0, 4), (1, 5)]:
        assert sum((c.section_i, c.section_j) == pair for c in cands) == 6
    P = T[:, :3, 3]
    for c in cands:
        assert c.i < c.j
        assert sections[c.section_i].first <= c.i <= sections[c.section_i].last
        assert sections[c.section_j].first <= c.j <= sections[c.section_j].last
        assert abs(c.l_i - c.l_j) < settings.pairing_tolerance_m
        # l_i ~ l_j means the same place: the true positions agree along the pipe to the tolerance.
        axis = sections[c.section_i].direction
        true_axis = T[c.i, :3, :3] @ D[c.i, :3, :3].T @ axis
        assert abs((P[c.j] - P[c.i]) @ true_axis) < settings.pairing_tolerance_m + 0.005
    # Spread along the overlap (1.5 m less the tee margins), not bunched at one end.
    for section in (0, 1):
        l = sorted(c.l_i for c in cands if c.section_i == section)
        assert l[-1] - l[0] > 0.9 and np.max(np.diff(l)) < 0.4


def test_visits_that_reach_different_tees_pair_by_position_along_the_pipe():
    """A loop that ends on the side it started on, short of the tee it first turned at: the first
    visit's tee is at the pipe's far end (x = 1.5), the second visit's at its near end (x = 0).
    Distances to those two tees do not name one place; positions along the axis do."""
    x = np.array([1.0, 0.0, 0.0])
    poses = np.stack([np.eye(4)] * 60)
    poses[:30, :3, 3] = np.linspace(0.5, 1.3, 30)[:, None] * x  # first visit, towards the tee at 1.5
    poses[30:, :3, 3] = np.linspace(0.2, 1.0, 30)[:, None] * x  # the last, from the tee at 0
    sections = [StraightSection(0, 29, [0, 0, 0], x), StraightSection(30, 59, [0, 0.002, 0], x)]
    junctions = [TeeJunction(np.array([1.5, 0, 0]), (0,)), TeeJunction(np.array([0.0, 0, 0]), (1,))]
    cands = loop_candidates(sections, junctions, poses, RADIUS, LoopClosureSettings(candidates_per_section=5))
    assert len(cands) == 5
    P = poses[:, :3, 3]
    for c in cands:
        assert abs(P[c.j, 0] - P[c.i, 0]) < 0.03 and 0.5 <= P[c.i, 0] <= 1.0


def test_same_pipe_needs_collinear_overlapping_axes():
    s = LoopClosureSettings()
    x = np.array([1.0, 0.0, 0.0])
    line = np.stack([np.eye(4)] * 40)
    line[:, :3, 3] = np.linspace(0, 3.9, 40)[:, None] * x
    a = StraightSection(0, 19, [0, 0, 0], x)  # x from 0 to 1.9
    assert same_pipe(a, StraightSection(20, 39, [0.05, 0.1, 0], x), line[:, :3, 3], RADIUS, s) is None  # no overlap
    back = line.copy()
    back[20:, :3, 3] = np.linspace(0.2, 1.8, 20)[:, None] * x + [0, 0.1, 0]
    back = back[:, :3, 3]
    overlap = same_pipe(a, StraightSection(20, 39, [0.0, 0.1, 0], -x), back, RADIUS, s)
    assert overlap is not None and abs(overlap[0] - 0.2) < 1e-9 and abs(overlap[1] - 1.8) < 1e-9
    assert same_pipe(a, StraightSection(20, 39, [0.0, 0.5, 0], x), back, RADIUS, s) is None  # a parallel pipe
    tilted = np.array([np.cos(0.2), np.sin(0.2), 0.0])
    assert same_pipe(a, StraightSection(20, 39, [0.0, 0.1, 0], tilted), back, RADIUS, s) is None


# -- relative pose of two rendered frames -------------------------------------------------------------


def segment_cylinder_in_camera(network, T: np.ndarray) -> Cylinder:
    """The true pipe piece the camera is in, as a cylinder in the camera's frame."""
    c = T[:3, 3]

    def dist(seg):
        h = np.clip((c - seg.start) @ seg.axis, 0, seg.length)
        return np.linalg.norm(c - seg.start - h * seg.axis)

    seg = min(network.segments, key=dist)
    return cylinder_in_camera(StraightSection(0, 0, seg.start, seg.axis), T, network.radius_m)


def true_relative(T, i, j):
    return compose(*invert(*as_rt(T[i])), *as_rt(T[j]))


def test_relative_pose_of_a_revisited_place(revisit):
    ds = load_dataset(revisit)
    T = read_tum(revisit / "ground_truth" / "poses.tum").matrices()
    network = load_network(revisit / "ground_truth" / "network.yaml")
    P, n = T[:, :3, 3], len(T)
    tee = network.junction("T4").centroid
    first = np.array([k for k in range(n // 3) if np.linalg.norm(P[k] - tee) > 0.45])
    later = np.arange(2 * n // 3, n)
    d = np.linalg.norm(P[first, None] - P[None, later], axis=-1)
    a, b = np.unravel_index(np.argmin(d), d.shape)
    i, j = int(first[a]), int(later[b])
    assert 0.002 < d[a, b] < 0.1 and j - i > n // 2
    edge = relative_pose(ds.camera, ds.read(i).image, ds.read(j).image, segment_cylinder_in_camera(network, T[i]),
                         segment_cylinder_in_camera(network, T[j]), Settings(), seed=0)
    assert edge is not None and edge.inliers >= 30
    R, t = true_relative(T, i, j)
    assert np.linalg.norm(edge.T_ij[:3, 3] - t) < 0.005
    assert np.degrees(rotation_angle(edge.T_ij[:3, :3].T @ R)) < 0.2
    assert np.degrees(edge.rms_rad) < 0.6  # about a pixel at 320 x 240
    sd = np.sqrt(np.diag(edge.covariance))
    assert np.all(sd[:3] < 0.005) and np.all(np.degrees(sd[3:]) < 0.2)
    np.testing.assert_allclose(edge.covariance, edge.covariance.T)
    # Two different places do not make an edge.
    assert relative_pose(ds.camera, ds.read(i).image, ds.read(n // 2).image, segment_cylinder_in_camera(network, T[i]),
                         segment_cylinder_in_camera(network, T[n // 2]), Settings(), seed=0) is None


def test_two_way_jacobian_matches_numerical():
    rng = np.random.default_rng(3)
    R, t = exp_so3(np.array([0.02, -0.03, 0.01])), np.array([0.01, -0.02, 0.03])
    X_i = rng.normal(size=(12, 3)) * 0.2 + [0, 0, 0.3]
    X_j = rng.normal(size=(12, 3)) * 0.2 + [0, 0, -0.3]
    b_i = rng.normal(size=(12, 3))
    b_j = rng.normal(size=(12, 3))
    b_i /= np.linalg.norm(b_i, axis=1, keepdims=True)
    b_j /= np.linalg.norm(b_j, axis=1, keepdims=True)
    problem = _TwoWayProblem(R, t, X_i, b_j, X_j, b_i)
    _, J = problem.residuals(jacobian=True)
    h = 1e-6
    numeric = np.stack([(problem.residuals(h * e) - problem.residuals(-h * e)) / (2 * h) for e in np.eye(6)], axis=1)
    np.testing.assert_allclose(J, numeric, atol=1e-7)
    # ... and the residuals are the angles: a point on the bearing has none.
    seen_j, seen_i = world_to_camera(R, t, X_i), X_j @ R.T + t
    on = _TwoWayProblem(R, t, X_i, seen_j / np.linalg.norm(seen_j, axis=1, keepdims=True), X_j,
                        seen_i / np.linalg.norm(seen_i, axis=1, keepdims=True))
    np.testing.assert_allclose(on.residuals(), 0.0, atol=1e-12)
    # A rotation of camera j by a small angle about an axis perpendicular to a bearing moves it by that angle.
    turned = on.moved(np.array([0, 0, 0, 0, 0, 1e-4]))
    err = np.linalg.norm(turned.residuals().reshape(2, -1, 2)[0], axis=1)
    sin_axis = np.linalg.norm(np.cross(on.b_j, [0, 0, 1.0]), axis=1)
    np.testing.assert_allclose(err, 1e-4 * sin_axis, rtol=1e-3)


def test_sift_matching_is_mutual_and_unambiguous():
    rng = np.random.default_rng(0)
    desc = rng.random((50, 128)).astype(np.float32)
    perm = rng.permutation(50)
    other = desc[perm] + rng.normal(scale=0.01, size=(50, 128)).astype(np.float32)
    other[0] = other[1] + 1e-4  # two near-identical descriptors in image j: ambiguous, both dropped
    ii, jj = match_sift(desc, other, 0.8)
    assert len(ii) == 48
    np.testing.assert_array_equal(perm[jj], ii)
    assert 0 not in jj and 1 not in jj


# -- the whole chain ----------------------------------------------------------------------------------


def test_close_loops_corrects_drifted_odometry(revisit):
    ds = load_dataset(revisit)
    T = read_tum(revisit / "ground_truth" / "poses.tum").matrices()
    network = load_network(revisit / "ground_truth" / "network.yaml")
    D = drift(T)
    sections, junctions, _ = route_map(T, D, network)
    result = close_loops(ds.camera, D, sections, junctions, lambda k: ds.read(k).image, RADIUS, Settings(), seed=0)
    assert len(result.edges) >= 5
    # Every measured edge agrees with ground truth.
    for c, e in result.edges:
        R, t = true_relative(T, c.i, c.j)
        assert np.linalg.norm(e.T_ij[:3, 3] - t) < 0.005
        assert np.degrees(rotation_angle(e.T_ij[:3, :3].T @ R)) < 0.5
    before = np.linalg.norm(D[:, :3, 3] - T[:, :3, 3], axis=1)
    after = np.linalg.norm(result.poses[:, :3, 3] - T[:, :3, 3], axis=1)
    revisited = np.arange(sections[4].first, len(T))
    assert before[revisited].max() > 0.07
    assert after[revisited].max() < before[revisited].max() / 5
    assert after[-1] < before[-1] / 5
    np.testing.assert_allclose(result.poses[0], D[0], atol=1e-12)


def test_close_loops_disabled_or_without_edges_keeps_the_poses(route):
    T, D, sections, junctions, _ = route
    off = Settings()
    off.loop_closure.enabled = False
    out = close_loops(None, D, sections, junctions, lambda k: None, RADIUS, off)
    np.testing.assert_array_equal(out.poses, D)
    assert out.edges == [] and out.candidates == []
    # Blank images: candidates exist, but no relative pose can be measured.
    blank = np.zeros((240, 320), np.uint8)
    from pipemap.sim.presets import fisheye_camera
    out = close_loops(fisheye_camera(320, 240), D, sections, junctions, lambda k: blank, RADIUS, Settings())
    assert len(out.candidates) > 0 and out.edges == []
    np.testing.assert_array_equal(out.poses, D)


def test_reanchor_moves_points_with_their_pose():
    rng = np.random.default_rng(2)
    before = to_matrix(exp_so3(rng.normal(size=(5, 3))), rng.normal(size=(5, 3)))
    after = to_matrix(exp_so3(rng.normal(size=(5, 3))), rng.normal(size=(5, 3)))
    X_cam = rng.normal(size=(5, 3))
    X = np.einsum("nij,nj->ni", before[:, :3, :3], X_cam) + before[:, :3, 3]
    moved = reanchor(X, before, after)
    # Each point keeps its place in its owner camera's frame.
    np.testing.assert_allclose(moved, np.einsum("nij,nj->ni", after[:, :3, :3], X_cam) + after[:, :3, 3], atol=1e-12)
    one = reanchor(X, before[0], after[0])
    np.testing.assert_allclose(one[0], moved[0], atol=1e-12)


def test_a_section_driven_there_and_back_is_two_visits_of_its_pipe():
    """A crawler drives 4.3 m along a pipe and reverses to 0.1 m (no junction): its one section splits into two
    legs at the turn, and the legs pair up where they overlap, as two visits of a pipe past its tees do. A step
    back shorter than loop_closure.min_overlap_m (a stop and a jolt) does not split a leg."""
    from pipemap.backend.revisit import section_legs

    lc = LoopClosureSettings()
    h = np.r_[np.linspace(0.0, 4.3, 88), np.linspace(4.28, 0.1, 78)]
    P = np.column_stack([0.001 * np.sin(h), np.zeros_like(h), h])
    axis = (np.zeros(3), np.array([0.0, 0.0, 1.0]))
    assert section_legs(P, *axis, lc.min_overlap_m) == [(0, 87), (88, 165)]
    jolt = np.r_[np.linspace(0.0, 2.0, 40), [1.9, 1.85], np.linspace(1.9, 3.0, 20)]
    assert section_legs(np.column_stack([0 * jolt, 0 * jolt, jolt]), *axis, lc.min_overlap_m) == [(0, 61)]
    back_first = np.r_[np.linspace(0.0, -2.0, 40), np.linspace(-1.9, 0.5, 40), np.linspace(0.4, -1.0, 20)]
    assert section_legs(np.column_stack([0 * back_first] * 2 + [back_first]), *axis,
                        lc.min_overlap_m) == [(0, 39), (40, 79), (80, 99)]
    poses = np.tile(np.eye(4), (len(h), 1, 1))
    poses[:, :3, 3] = P
    legs = [StraightSection(a, b, *axis) for a, b in section_legs(P, *axis, lc.min_overlap_m)]
    pairs = loop_candidates(legs, [], poses, 0.2, lc)
    assert len(pairs) == lc.candidates_per_section
    assert all(c.i <= 87 < c.j and abs(P[c.i, 2] - P[c.j, 2]) < lc.pairing_tolerance_m for c in pairs)
