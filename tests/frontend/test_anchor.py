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
