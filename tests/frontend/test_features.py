"""Region Harris corners and template descriptors."""

import cv2
import numpy as np

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
