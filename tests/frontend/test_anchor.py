"""Anchor matches: affine Lucas-Kanade against each track's first patch (frontend/anchor.py)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from pipemap.frontend.anchor import anchor_templates, refine_to_anchors

PATCH = 11


def _texture(size=240, seed=0):
    rng = np.random.default_rng(seed)
    img = cv2.GaussianBlur(rng.normal(0, 1, (size, size)).astype(np.float32), (0, 0), 1.5)
    return 40.0 * img / img.std()


def _warped(img, A, shift, centre, gain=1.0, offset=0.0):
    """img seen through x' = centre + A (x - centre) + shift, with a gain and an offset."""
    M = np.zeros((2, 3))
    M[:, :2] = A
    M[:, 2] = centre + shift - A @ centre
    out = cv2.warpAffine(img, M, img.shape[::-1], flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT101)
    return gain * out + offset


def _grid_points(n=6, lo=60, hi=180):
    g = np.linspace(lo, hi, n)
    return np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)


def test_recovers_a_warped_shifted_relit_patch():
    img = _texture()
    pts = _grid_points()
    centre = np.array([120.0, 120.0])
    A = np.array([[1.06, 0.02], [-0.01, 0.97]])
    shift = np.array([0.37, -0.61])
    moved = _warped(img, A, shift, centre, gain=1.2, offset=5.0)
    truth = centre + (pts - centre) @ A.T + shift
    anchors = anchor_templates(img, pts, PATCH)
    start = truth + np.random.default_rng(1).uniform(-0.6, 0.6, truth.shape)
    ok, pos, anchors = refine_to_anchors(moved, anchors, start, PATCH, iterations=10)
    warps = anchors.warps
    assert ok.all()
    # Bilinear resampling of the moved image alone leaves a few hundredths of a pixel.
    assert np.abs(pos - truth).max() < 0.08 and np.median(np.linalg.norm(pos - truth, axis=1)) < 0.05
    assert np.abs(warps - A).max() < 0.02


def test_error_does_not_grow_along_a_track():
    """Twenty frames, each magnified 1.5 % more and moved 0.43 px: matched against the anchor with the
    warp carried over, the last frame is as exact as the first."""
    img = _texture(seed=2)
    pts = _grid_points(5, 80, 160)
    centre = np.array([120.0, 120.0])
    anchors = anchor_templates(img, pts, PATCH)
    pos = pts.copy()
    errors = []
    for k in range(1, 21):
        A = np.eye(2) * 1.015**k
        shift = np.array([0.43, 0.17]) * k
        truth = centre + (pts - centre) @ A.T + shift
        frame = _warped(img, A, shift, centre)
        start = pos + (truth - pos) + np.random.default_rng(k).uniform(-0.5, 0.5, truth.shape)  # a ZNCC-like guess
        ok, pos, anchors = refine_to_anchors(frame, anchors, start, PATCH)
        assert ok.mean() > 0.9
        errors.append(np.median(np.linalg.norm(pos - truth, axis=1)))
    assert max(errors) < 0.06
    assert errors[-1] < 0.06


def test_a_different_patch_is_refused_and_keeps_its_inputs():
    img = _texture(seed=3)
    other = _texture(seed=4)
    pts = _grid_points(3)
    anchors = anchor_templates(img, pts, PATCH)
    anchors.warps *= 1.01
    start = pts + 0.2
    ok, pos, out = refine_to_anchors(other, anchors, start, PATCH)
    assert not ok.any()
    assert np.array_equal(pos, start) and np.array_equal(out.warps, anchors.warps)


def test_a_warp_that_runs_away_is_refused_not_raised():
    # Matched against an unrelated image for many iterations, warps grow without bound; the SVD of
    # such a warp did not converge and raised (seen with anchor_iterations 30 on a junction run).
    img = _texture(seed=3)
    pts = _grid_points(4)
    anchors = anchor_templates(img, pts, PATCH)
    start = pts + 0.3
    ok, pos, out = refine_to_anchors(_texture(seed=4), anchors, start, PATCH, iterations=60)
    assert not ok.any()
    assert np.array_equal(pos, start) and np.array_equal(out.warps, anchors.warps)


def test_empty_input():
    img = _texture()
    anchors = anchor_templates(img, np.zeros((0, 2)), PATCH)
    assert anchors.templates.shape == (0, PATCH * PATCH) and len(anchors) == 0
    ok, pos, out = refine_to_anchors(img, anchors, np.zeros((0, 2)), PATCH)
    assert ok.shape == (0,) and pos.shape == (0, 2) and out.warps.shape == (0, 2, 2)


@pytest.mark.parametrize("shift_px", [1.0, 3.0])
def test_shift_limit(shift_px):
    img = _texture(seed=5)
    pts = _grid_points(3)
    moved = _warped(img, np.eye(2), np.array([shift_px, 0.0]), np.array([120.0, 120.0]))
    ok, _, _ = refine_to_anchors(moved, anchor_templates(img, pts, PATCH), pts, PATCH, iterations=20,
                                 max_shift_px=1.5)
    assert ok.all() if shift_px < 1.5 else not ok.any()


def _bent_frame(img, H):
    """img seen through a motion that bends: the pixel at y shows img at y + 1/2 (y-c)^T H_k (y-c),
    c the image centre. Returns the frame and the motion's inverse (template -> frame) by Newton."""
    c = np.array(img.shape[::-1], float) / 2

    def source(y):
        d = y - c
        return y + 0.5 * np.einsum("...a,kab,...b->...k", d, H, d)

    h, w = img.shape
    ys = np.stack(np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float)), -1)
    src = source(ys).astype(np.float32)
    frame = cv2.remap(img, src[..., 0], src[..., 1], cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT101)

    def to_frame(x):
        y = np.array(x, float)
        for _ in range(30):
            d = y - c
            J = np.eye(2) + np.einsum("kab,...b->...ka", H, d)
            y = y - np.linalg.solve(J, (source(y) - x)[..., None])[..., 0]
        return y

    return frame, to_frame


def test_a_bent_motion_is_matched_without_bias_once_its_bend_is_carried():
    """An affine warp fitted to a motion that bends across the window misplaces the centre by about
    H w^2 / 6, the same way for every patch; with the bend carried, the bias goes."""
    from pipemap.frontend.flow import local_quadratic_motion

    img = _texture(size=300, seed=6)
    Hs = np.array([[[0.006, 0.0], [0.0, 0.004]], [[0.0, 0.003], [0.003, 0.0]]])
    frame, to_frame = _bent_frame(img, Hs)
    rng = np.random.default_rng(7)
    pts = rng.uniform(90, 210, (60, 2))
    truth = to_frame(pts)
    start = truth + rng.uniform(-0.5, 0.5, truth.shape)
    anchors = anchor_templates(img, pts, PATCH)
    ok0, pos0, _ = refine_to_anchors(frame, anchors, start, PATCH, iterations=15)
    # the bend, as the tracker measures it: from the matches of many points around each one
    cloud = rng.uniform(40, 260, (1500, 2))
    J, H, okf = local_quadratic_motion(cloud, to_frame(cloud), pts)
    assert okf.all()
    ok1, pos1, _ = refine_to_anchors(frame, anchors.carry(J, H), start, PATCH, iterations=15)
    assert ok0.all() and ok1.all()
    bias0 = np.abs(np.mean(pos0 - truth, axis=0)).max()
    bias1 = np.abs(np.mean(pos1 - truth, axis=0)).max()
    assert bias0 > 0.05  # what the affine match alone leaves
    assert bias1 < 0.015


@pytest.mark.parametrize("stretch", [np.diag([2.3, 1.0]), np.diag([1.0, 1 / 2.3])])
def test_a_patch_stretched_past_the_limit_is_refused(stretch):
    img = _texture(seed=8)
    pts = _grid_points(3, 100, 140)
    centre = np.array([120.0, 120.0])
    moved = _warped(img, stretch, np.zeros(2), centre)
    truth = centre + (pts - centre) @ stretch.T
    anchors = anchor_templates(img, pts, PATCH)
    anchors.warps[:] = stretch  # carried from earlier keyframes
    ok, pos, _ = refine_to_anchors(moved, anchors, truth, PATCH, max_stretch=3.0)
    assert ok.all() and np.abs(pos - truth).max() < 0.1
    ok, pos, _ = refine_to_anchors(moved, anchors, truth, PATCH, max_stretch=2.0)
    assert not ok.any() and np.array_equal(pos, truth)


def test_bilinear_samples_and_shifted_windows_are_exact():
    """Both samplers against scipy's bilinear interpolation in float64, edges clamped: within float32 rounding
    (cv2.remap's own bilinear mode is 1/32 px coarse, 0.03 px of match error)."""
    from scipy.ndimage import map_coordinates

    from pipemap.frontend.anchor import _Bilinear, _shifted_windows

    img = _texture(120, seed=3).astype(np.float32)
    rng = np.random.default_rng(1)
    u, v = rng.uniform(-2, 122, (40, 30)).astype(np.float32), rng.uniform(-2, 122, (40, 30)).astype(np.float32)
    truth = map_coordinates(img.astype(np.float64), [np.clip(v, 0, 118.999), np.clip(u, 0, 118.999)], order=1)
    assert np.abs(_Bilinear(img)(u, v) - truth).max() < 1e-4 * 255

    pts = rng.uniform(10, 110, (25, 2)).astype(np.float32)
    windows = _shifted_windows(img, pts, 4)
    o = np.arange(-4, 5)
    cols, rows = pts[:, 0, None, None] + o[None, None, :], pts[:, 1, None, None] + o[None, :, None]
    truth = map_coordinates(img.astype(np.float64), [np.broadcast_to(rows, windows.shape),
                                                     np.broadcast_to(cols, windows.shape)], order=1)
    assert np.abs(windows - truth).max() < 1e-4 * 255


def test_a_light_fixed_in_the_image_is_projected_out():
    """The robot's light stays where it is in the image while the wall moves: a quadratic brightness field fixed in
    the image differs between a template and its match. Projected out (6 terms) it leaves the interpolation's
    few hundredths of a pixel; with the mean alone (ZNCC) its gradient pulls the worst matches more than 0.1 px."""
    img = _texture(seed=11)
    h, w = img.shape
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    light = 0.05 * ((x - 120) ** 2 + 0.5 * (y - 120) ** 2 + 0.3 * (x - 120) * (y - 120))
    pts = _grid_points(6)
    centre = np.array([120.0, 120.0])
    A, shift = np.eye(2) * 1.05, np.array([5.3, -3.1])
    moved = _warped(img, A, shift, centre) + light
    truth = centre + (pts - centre) @ A.T + shift
    worst = {}
    for terms in (1, 6):
        anchors = anchor_templates(img + light, pts, PATCH, terms)
        ok, pos, _ = refine_to_anchors(moved, anchors, truth + 0.3, PATCH, iterations=15, brightness_terms=terms)
        assert ok.all()
        worst[terms] = np.linalg.norm(pos - truth, axis=1).max()
    assert worst[6] < 0.08
    assert worst[1] > 0.11


def test_a_magnified_patch_keeps_its_place_on_log_brightness():
    """A high-pass filter fixed in the image (the flattened image) passes another band of the wall's texture once a
    patch is magnified, and the match slides; log brightness less a quadratic per patch compares the same texture
    at any stretch. Texture with structure at 1.2 and 4 px, magnified 1.8 times."""
    from pipemap.frontend.harris import _local_mean

    rng = np.random.default_rng(0)
    fine = cv2.GaussianBlur(rng.normal(0, 1, (240, 240)).astype(np.float32), (0, 0), 1.2)
    coarse = cv2.GaussianBlur(rng.normal(0, 1, (240, 240)).astype(np.float32), (0, 0), 4.0)
    wall = fine / fine.std() + 0.5 * coarse / coarse.std()
    wall = 40 * wall / wall.std()
    centre, A, shift = np.array([120.0, 120.0]), np.eye(2) * 1.8, np.array([0.4, -0.2])
    pts = _grid_points(6, 90, 150)
    moved = _warped(wall, A, shift, centre)
    truth = centre + (pts - centre) @ A.T + shift

    def median_error(template_image, image, terms):
        anchors = anchor_templates(template_image, pts, PATCH, terms)
        anchors.warps[:] = A  # carried from earlier keyframes
        ok, pos, _ = refine_to_anchors(image, anchors, truth + 0.3, PATCH, iterations=15, brightness_terms=terms)
        assert ok.all()
        return np.median(np.linalg.norm(pos - truth, axis=1))

    flattened = median_error(wall - _local_mean(wall, 4.0), moved - _local_mean(moved, 4.0), 1)
    quadratic = median_error(wall, moved, 6)
    assert quadratic < 0.025
    assert flattened > 0.1


def test_brightness_terms_are_orthonormal_polynomials():
    from pipemap.frontend.anchor import _brightness_basis, _offsets

    g = _offsets(PATCH)
    for terms in (1, 3, 6):
        B = _brightness_basis(PATCH, terms).astype(np.float64)
        assert np.allclose(B @ B.T, np.eye(terms), atol=1e-5)
        poly = np.stack([np.ones(len(g)), g[:, 0], g[:, 1], g[:, 0] ** 2, g[:, 0] * g[:, 1], g[:, 1] ** 2])[:terms]
        assert np.allclose(poly - (poly @ B.T) @ B, 0, atol=1e-3 * np.abs(poly).max())
    with pytest.raises(ValueError):
        _brightness_basis(PATCH, 4)
