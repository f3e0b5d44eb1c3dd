"""Region Harris corners and template descriptors."""

import cv2
import numpy as np
import pytest

from pipemap.frontend.descriptors import describe, match_descriptors, smooth_for_templates
from pipemap.frontend.harris import detect_corners, valid_mask


def test_corners_lie_in_the_fisheye_circle_capped_per_region(pipe_scene):
    cam, image = pipe_scene.camera, pipe_scene.images[0]
    mask = valid_mask(cam, 16)
    pts, _ = detect_corners(image, mask, (2, 2), 50)
    assert 150 <= len(pts) <= 200
    u, v = np.rint(pts).astype(int).T
    assert np.all(mask[v, u] > 0)
    region = (v * 2 // cam.height) * 2 + (u * 2 // cam.width)
    assert np.bincount(region, minlength=4).max() <= 50
    assert np.bincount(region, minlength=4).min() >= 40  # a uniform spread, not all in the brightest region
    assert valid_mask(cam, 16) is mask  # cached per camera


def test_corner_positions_follow_a_sub_pixel_shift(pipe_scene):
    image = cv2.GaussianBlur(pipe_scene.images[0], (0, 0), 0.7)
    shift = np.array([0.3, 0.6])
    moved = cv2.warpAffine(image, np.array([[1, 0, shift[0]], [0, 1, shift[1]]]), image.shape[::-1],
                           flags=cv2.INTER_CUBIC)
    mask = valid_mask(pipe_scene.camera, 20)
    a, _ = detect_corners(image, mask, (2, 2), 100)
    b, _ = detect_corners(moved, mask, (2, 2), 100)
    d = np.linalg.norm(a[:, None, :] + shift - b[None, :, :], axis=2)
    nearest = d.min(axis=1)
    err = nearest[nearest < 1.0]
    assert len(err) > 0.7 * len(a)
    assert np.median(err) < 0.3  # integer positions would be off by ~0.5 px; 640 x 480 gives 0.13


def test_saturated_frame_has_no_corners_and_no_descriptors():
    img = np.full((240, 320), 255.0, np.float32)
    pts, _ = detect_corners(img, np.ones((240, 320), np.uint8))
    assert len(pts) == 0
    d, ok = describe(smooth_for_templates(img), np.array([[160.0, 120.0]]))
    assert not ok[0] and np.all(d == 0)


def test_descriptors_ignore_gain_and_offset_and_match_a_shifted_image(pipe_scene):
    cam, image = pipe_scene.camera, pipe_scene.images[0]
    pts, _ = detect_corners(image, valid_mask(cam, 20), (2, 2), 100)
    d1, ok1 = describe(smooth_for_templates(image), pts)
    d2, _ = describe(smooth_for_templates(0.5 * image + 30.0), pts)
    assert np.all(ok1)
    assert np.allclose(np.sum(d1 * d2, axis=1), 1.0, atol=1e-4)
    assert np.allclose(np.linalg.norm(d1, axis=1), 1.0, atol=1e-5) and np.allclose(d1.mean(axis=1), 0.0, atol=1e-5)
    shift = np.array([3.0, -2.0])
    moved = np.roll(image, (-2, 3), axis=(0, 1))
    pts2, _ = detect_corners(moved, valid_mask(cam, 20), (2, 2), 100)
    d3, _ = describe(smooth_for_templates(moved), pts2)
    i, j, sim = match_descriptors(d1, d3, pts, pts2, ratio=0.9, max_flow_px=20)
    assert len(i) > 0.5 * len(pts)
    correct = np.linalg.norm(pts2[j] - pts[i] - shift, axis=1) < 0.5
    assert correct.mean() > 0.95
    # Mutual: no point of either image is used twice.
    assert len(set(i)) == len(i) and len(set(j)) == len(j)


@pytest.mark.parametrize("seed", range(6))
def test_matching_within_the_flow_limit_equals_masking_every_pair(seed):
    """The band search (corners in order of u, only image j's within reach of each group) finds the same mutual,
    ratio-tested matches as the similarity of every pair with the far ones masked, corners exactly at the limit
    included."""
    rng = np.random.default_rng(seed)
    n, m = int(rng.integers(1, 900)), int(rng.integers(1, 1100))
    di = rng.normal(size=(n, 121)).astype(np.float32)
    di /= np.linalg.norm(di, axis=1, keepdims=True)
    k = min(n, m)
    dj = rng.normal(size=(m, 121)).astype(np.float32)
    dj[:k] = di[:k] + 0.1 * rng.normal(size=(k, 121)).astype(np.float32)
    dj /= np.linalg.norm(dj, axis=1, keepdims=True)
    pi = rng.uniform(0, [640, 480], (n, 2)).astype(np.float32)
    pj = rng.uniform(0, [640, 480], (m, 2)).astype(np.float32)
    pj[:k] = pi[:k] + rng.normal(0, 30, (k, 2))
    pi[:3], pj[:3] = [100.0, 50.0], [180.0, 50.0]  # 80 px apart: still candidates
    sim = di @ dj.T
    sim[((pi[:, None] - pj[None]) ** 2).sum(axis=2) > np.float32(80.0**2)] = -2.0
    rows = np.arange(n)
    best_j = sim.argmax(axis=1)
    best = sim[rows, best_j].copy()
    mutual = sim.argmax(axis=0)[best_j] == rows
    sim[rows, best_j] = -3.0
    second = sim.max(axis=1) if m > 1 else np.full(n, -2.0)
    good = mutual & ((1 - best) < 0.9 * (1 - second)) & (best >= 0.5)
    i, j, s = match_descriptors(di, dj, pi, pj, ratio=0.9, min_similarity=0.5, max_flow_px=80.0)
    assert np.array_equal(i, rows[good]) and np.array_equal(j, best_j[good])
    assert np.allclose(s, best[good], atol=1e-6)
