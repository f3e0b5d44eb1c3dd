"""Appearance map: wall pieces and grids, tee openings, line of sight, grey levels against the
simulator's texture, the PLY file."""

from __future__ import annotations

import numpy as np
import pytest

from pipemap.config import AppearanceSettings
from pipemap.errors import PipemapError
from pipemap.mapping import (WallPiece, build_appearance, read_appearance_ply, sample_wall, wall_grid,
                             write_appearance_ply)
from pipemap.mapping.wall import in_line_of_sight, inside_piece

from mapping_helpers import texture_correlation

R = 0.2


def test_grid_spacing_and_clock_convention():
    piece = WallPiece("S1", [0, 0, 0], [1.0, 0, 0], R, [0, 0, 5.0])
    grid = wall_grid(piece, 0.002)
    assert grid.shape == (501, 628)
    assert grid.spacing_h == pytest.approx(0.002)
    assert grid.spacing_around == pytest.approx(2 * np.pi * R / 628)
    P = grid.points()
    # phi = 0 is 12 o'clock (+z); phi = pi/2 is 3 o'clock looking along +x, i.e. -y
    np.testing.assert_allclose(P[0, 0], [0, 0, R], atol=1e-12)
    np.testing.assert_allclose(P[10, 157], [0.02, -R, 0], atol=1e-12)
    h, phi, rho = piece.wall_coordinates(P)
    np.testing.assert_allclose(h, np.broadcast_to(grid.h[:, None], h.shape), atol=1e-12)
    np.testing.assert_allclose(phi, np.broadcast_to(grid.phi[None, :], phi.shape), atol=1e-12)
    np.testing.assert_allclose(rho, R, atol=1e-12)


@pytest.mark.parametrize("kwargs, message", [
    (dict(end=[0, 0, 0]), "same point"),
    (dict(radius=0.0), "radius"),
    (dict(up=[1.0, 0, 0]), "parallel"),
    (dict(start=[0, np.nan, 0]), "finite"),
])
def test_bad_piece_raises(kwargs, message):
    args = dict(name="S1", start=[0, 0, 0], end=[1.0, 0, 0], radius=R, up=[0, 0, 1.0]) | kwargs
    with pytest.raises(PipemapError, match=message):
        WallPiece(**args)


def tee():
    main = WallPiece("S1", [-1.0, 0, 0], [1.0, 0, 0], R, [0, 0, 1.0])
    branch = WallPiece("T1-branch", [0, 0, 0], [0, 1.0, 0], R, [0, 0, 1.0])
    return main, branch


def test_tee_opening_is_cut_from_the_main_wall_only_on_the_branch_side():
    main, branch = tee()
    spacing = 0.004
    P, keep = sample_wall(main, spacing, [main, branch])
    # analytically: the branch solid is x^2 + z^2 < r^2 on the +y side
    margin = spacing  # INSIDE_MARGIN_SPACINGS = 1
    hole = (P[..., 0] ** 2 + P[..., 2] ** 2 < (R - margin) ** 2) & (P[..., 1] > 0)
    np.testing.assert_array_equal(~keep, hole)
    # the hole's area on the main wall: int over z of 2 sqrt(r^2 - z^2) dz... ~ pi r^2 / ... measured
    area = (~keep).sum() * spacing * (2 * np.pi * R / P.shape[1])
    # area of the branch opening on the main cylinder: int_{-r}^{r} 2 sqrt(r^2 - x^2) * (dz/ds) ds = 4 r^2
    # (exact: 4 r^2)
    assert area == pytest.approx(4 * (R - margin) ** 2, rel=0.05)
    Pb, keep_b = sample_wall(branch, spacing, [main, branch])
    inside_main = Pb[..., 1] ** 2 + Pb[..., 2] ** 2 < (R - spacing) ** 2
    np.testing.assert_array_equal(~keep_b, inside_main)


def _brute_sight(c, P, pieces, steps=2000, tol=1e-3):
    f = (np.arange(steps) + 0.5) / steps
    S = c + f[None, :, None] * (P - c)[:, None, :]
    ok = np.zeros(S.shape[:2], bool)
    for p in pieces:
        ok |= inside_piece(S, p, -tol, tol)
    return ok.all(axis=1)


def test_line_of_sight_through_a_tee_opening():
    main, branch = tee()
    c = np.array([-0.5, 0.0, 0.0])
    assert in_line_of_sight(c, np.array([[0.15, 0.3, 0.0]]), [main, branch], 1e-3)[0]  # through the opening
    assert not in_line_of_sight(c, np.array([[-R, 0.6, 0.0]]), [main, branch], 1e-3)[0]  # behind the main wall
    rng = np.random.default_rng(0)
    grid = wall_grid(branch, 0.01)
    P = grid.points().reshape(-1, 3)
    P = P[rng.choice(len(P), 1000, replace=False)]
    for c in ([-0.5, 0.0, 0.05], [0.4, -0.1, 0.0], [-0.3, 0.05, -0.1]):
        fast = in_line_of_sight(np.array(c), P, [main, branch], 1e-3)
        slow = _brute_sight(np.array(c), P, [main, branch])
        assert fast.any() and (~fast).any()
        assert np.mean(fast == slow) > 0.995


def test_map_points_lie_on_the_true_wall(loop_case, loop_map):
    P, I = loop_map.points()
    assert len(P) > 300_000
    scene = loop_case.scene
    # distance to the nearest true wall: |rho - r| over the pieces whose length the point is beside
    best = np.full(len(P), np.inf)
    for pipe in scene.pipes:
        q = P - pipe.start
        h = q @ pipe.axis
        rho = np.linalg.norm(q - h[:, None] * pipe.axis, axis=1)
        beside = (h >= -pipe.extend_start - 1e-3) & (h <= pipe.length + pipe.extend_end + 1e-3)
        best = np.where(beside, np.minimum(best, np.abs(rho - scene.radius)), best)
    assert np.max(best) < 0.002
    # ... and none lies inside the pipe (a tee opening is not wall)
    assert not scene.contains(P, tol=0.002).any()
    assert np.all((I >= 0) & (I <= 255))


def test_grey_levels_follow_the_wall_texture(loop_case, loop_map):
    good = texture_correlation(loop_case, loop_map)
    assert good > 0.6
    # the same keyframes with poses 3 cm further along the path: the texture no longer lines up
    P = loop_case.poses.copy()
    c = P[:, :3, 3]
    tangent = np.gradient(c, axis=0)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    P[:, :3, 3] = c + 0.03 * tangent
    shifted = build_appearance(loop_case.dataset, loop_case.indices, P, loop_case.pieces, AppearanceSettings())
    assert texture_correlation(loop_case, shifted) < 0.5 * good


def test_maps_from_disjoint_keyframes_agree(loop_case, loop_map):
    c = loop_case
    even = build_appearance(c.dataset, c.indices[::2], c.poses[::2], c.pieces, AppearanceSettings())
    odd = build_appearance(c.dataset, c.indices[1::2], c.poses[1::2], c.pieces, AppearanceSettings())
    a, b = [], []
    for pe, po in zip(even.pieces, odd.pieces):
        both = pe.seen & po.seen
        a.append(pe.intensity[both])
        b.append(po.intensity[both])
    assert np.corrcoef(np.concatenate(a), np.concatenate(b))[0, 1] > 0.9
    assert even.keyframes == 30 and odd.keyframes == 30


def test_band_limits_are_respected(loop_case):
    c = loop_case
    narrow = AppearanceSettings(min_theta_deg=70.0, max_theta_deg=80.0, edge_taper_deg=0.0)
    amap = build_appearance(c.dataset, c.indices[:1], c.poses[:1], c.pieces, narrow)
    P, _ = amap.points()
    R_wc, t = c.poses[0, :3, :3], c.poses[0, :3, 3]
    X = (P - t) @ R_wc
    theta = np.degrees(np.arctan2(np.hypot(X[:, 0], X[:, 1]), X[:, 2]))
    assert len(P) > 1000
    assert theta.min() > 70.0 and theta.max() < 80.0
    assert amap.projections > amap.samples > 0


def test_appearance_ply_round_trip(tmp_path):
    rng = np.random.default_rng(1)
    P = rng.normal(size=(500, 3))
    I = rng.uniform(0, 255, 500)
    I[3] = np.nan  # dropped
    write_appearance_ply(tmp_path / "appearance.ply", P, I)
    Q, J = read_appearance_ply(tmp_path / "appearance.ply")
    keep = np.isfinite(I)
    np.testing.assert_allclose(Q, P[keep].astype(np.float32), atol=0)
    np.testing.assert_array_equal(J, np.rint(I[keep]).astype(np.uint8))
    header = (tmp_path / "appearance.ply").read_bytes()[:300].decode("ascii", "replace")
    assert "binary_little_endian" in header and "property float x" in header and "property uchar intensity" in header


def test_appearance_ply_written_in_parts_is_the_same_file(tmp_path):
    """write_maps writes the map piece by piece (never the whole map twice in memory): the same bytes as one
    write of all points, chainage and clock included, and plyfile reads it."""
    from plyfile import PlyData

    from pipemap.mapping import write_appearance_ply_parts

    rng = np.random.default_rng(2)
    P, I = rng.normal(size=(700, 3)), rng.uniform(0, 255, 700)
    P[10] = np.nan
    coords = (rng.uniform(0, 30, 700), rng.uniform(0, 360, 700))
    write_appearance_ply(tmp_path / "whole.ply", P, I, coords)
    cuts = [0, 1, 250, 251, 700]
    parts = [(P[a:b], I[a:b], (coords[0][a:b], coords[1][a:b])) for a, b in zip(cuts, cuts[1:])]
    assert write_appearance_ply_parts(tmp_path / "parts.ply", iter(parts), with_coords=True) == 699
    assert (tmp_path / "parts.ply").read_bytes() == (tmp_path / "whole.ply").read_bytes()
    v = PlyData.read(str(tmp_path / "parts.ply"))["vertex"]
    np.testing.assert_allclose(np.asarray(v["chainage"]), np.delete(coords[0], 10).astype(np.float32), atol=0)


def test_bad_inputs_raise(loop_case):
    c = loop_case
    with pytest.raises(PipemapError, match="3 keyframe indices but 2 poses"):
        build_appearance(c.dataset, [0, 1, 2], c.poses[:2], c.pieces)
    with pytest.raises(PipemapError, match="outside the dataset"):
        build_appearance(c.dataset, [10_000], c.poses[:1], c.pieces)
    with pytest.raises(PipemapError, match="min_theta_deg"):
        build_appearance(c.dataset, [0], c.poses[:1], c.pieces, AppearanceSettings(min_theta_deg=90, max_theta_deg=60))


def test_map_written_a_few_rows_at_a_time_holds_every_seen_point(loop_case, loop_map, tmp_path, monkeypatch):
    """write_maps locates and writes the map PLY_ROWS grid rows at a time (a whole piece's points and route
    coordinates at once were the run's peak of memory): the file holds exactly the seen points, piece after
    piece in grid order, with their grey levels, however small the blocks."""
    from pipemap.mapping import appearance

    monkeypatch.setattr(appearance, "PLY_ROWS", 7)
    c = loop_case
    appearance.write_maps(tmp_path, c.dataset, c.indices, c.poses, c.pieces)
    Q, J = read_appearance_ply(tmp_path / "appearance.ply")
    P, I = loop_map.points()
    np.testing.assert_array_equal(Q, P.astype(np.float32))
    np.testing.assert_array_equal(J, np.clip(np.rint(I), 0, 255).astype(np.uint8))


def test_sums_are_kept_only_for_the_wall_around_the_camera(loop_case, loop_map, monkeypatch):
    """The weighted sums live in blocks of ACCUMULATOR_ROWS grid rows, made when a keyframe first samples
    them and turned into grey levels once no later keyframe reaches them: the same map however the rows are
    blocked, while only part of the wall holds sums at any time."""
    from pipemap.mapping import appearance

    live, most = [0], [0]
    block, close = appearance._Sums._block, appearance._Sums.close

    def counting_block(self, b):
        if b not in self.blocks:
            live[0] += 1
            most[0] = max(most[0], live[0])
        return block(self, b)

    def counting_close(self, b):
        live[0] -= b in self.blocks
        close(self, b)

    monkeypatch.setattr(appearance._Sums, "_block", counting_block)
    monkeypatch.setattr(appearance._Sums, "close", counting_close)
    monkeypatch.setattr(appearance, "ACCUMULATOR_ROWS", 5)
    c = loop_case
    blocked = build_appearance(c.dataset, c.indices, c.poses, c.pieces, AppearanceSettings())
    rows = sum(pm.grid.shape[0] for pm in blocked.pieces)
    assert live[0] == 0 and most[0] < 0.3 * rows / 5  # 18 % on this route
    for a, b in zip(blocked.pieces, loop_map.pieces):
        np.testing.assert_array_equal(a.seen, b.seen)
        np.testing.assert_allclose(a.intensity[a.seen], b.intensity[b.seen], rtol=1e-6)
