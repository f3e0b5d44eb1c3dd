"""The sparse method's defences against oblique views: matches registered patch to patch from keyframe to
keyframe, and observations of wall seen too obliquely left out of the bundle on the wall."""

from __future__ import annotations

import cv2
import numpy as np

from pipemap.camera import PinholeCamera
from pipemap.config import SparseSettings
from pipemap.straight.sparse.batch import oblique
from pipemap.straight.sparse.features import Keypoints
from pipemap.straight.sparse.keyframes import KeyframeSelector, View

RADIUS = 0.19378


def test_oblique_is_the_angle_from_the_wall_normal():
    C = np.array([0.0, -0.04, 0.0])  # 4 cm below the axis, which is the pipe frame's h (third) axis
    depth = RADIUS + 0.04  # to the wall straight above
    along = depth * np.tan(np.radians([54.9, 55.1]))  # points up the pipe seen just inside and outside 55 deg
    X = np.stack([np.zeros(2), np.full(2, RADIUS), along], axis=1)
    assert oblique(X, np.tile(C, (2, 1)), 55.0).tolist() == [False, True]
    assert not oblique(X, np.tile(C, (2, 1)), None).any()
    # round the pipe: a point beside the camera is judged by the normal there, not by "up"
    side = np.array([[RADIUS * np.sin(0.3), RADIUS * np.cos(0.3), 0.0]])
    ray = side[0] - C
    incidence = np.degrees(np.arccos(ray @ side[0] / (np.linalg.norm(ray) * RADIUS)))
    assert oblique(side, C[None], incidence - 0.1)[0] and not oblique(side, C[None], incidence + 0.1)[0]


def _blobs(rng, n=1500):
    return rng.uniform([-20, -20], [340, 260], (n, 2)), rng.normal(0.0, 60.0, n)


def _render(blobs, A, shape=(240, 320), sigma=1.8):
    """Exact image of a texture of Gaussian spots seen through the affine motion A (2, 3), each spot evaluated
    on the pixels near where it lands."""
    centres, weights = blobs
    A_inv = cv2.invertAffineTransform(A)
    out = np.full(shape, 128.0)
    r = int(np.ceil(5 * sigma))
    for c, w in zip(centres @ A[:, :2].T + A[:, 2], weights):
        u0, v0 = int(round(c[0])), int(round(c[1]))
        rows, cols = (max(v0 - r, 0), min(v0 + r + 1, shape[0])), (max(u0 - r, 0), min(u0 + r + 1, shape[1]))
        if rows[0] >= rows[1] or cols[0] >= cols[1]:
            continue
        v, u = np.mgrid[rows[0]:rows[1], cols[0]:cols[1]]
        x = np.stack([u, v], axis=-1) @ A_inv[:, :2].T + A_inv[:, 2]  # back in the texture
        x0 = A_inv[:, :2] @ c + A_inv[:, 2]
        out[v, u] += w * np.exp(-np.sum((x - x0) ** 2, axis=-1) / (2 * sigma**2))
    return out.astype(np.float32)


def test_registration_places_each_match_on_the_previous_keyframes_wall_point():
    """Two exact views of a texture related by a known affine motion (a 2 % stretch and a 15.3 px move, as
    between keyframes of a wall camera): keypoints found 0.3 px off in the second view land a tenth of that from
    where the first view's points went (15 px patches, bilinear samples), and not off to one side on average."""
    rng = np.random.default_rng(3)
    blobs = _blobs(rng)
    A = np.array([[1.02, 0.01, -15.3], [-0.005, 1.0, 0.4]])
    first = _render(blobs, np.array([[1.0, 0, 0], [0, 1.0, 0]]))
    second = _render(blobs, A)
    uv1 = np.stack([rng.uniform(60, 260, 80), rng.uniform(40, 200, 80)], axis=1)
    truth = uv1 @ A[:, :2].T + A[:, 2]
    found = truth + rng.normal(0.0, 0.3, truth.shape)
    camera = PinholeCamera(320, 240, dict(fx=240.0, fy=240.0, cx=159.5, cy=119.5, k1=0, k2=0, p1=0, p2=0, k3=0))

    def view(index, uv, image):
        kp = Keypoints(uv, np.ones(len(uv)), np.zeros((len(uv), 128), np.float32))
        bearings, valid = camera.unproject(uv)
        return View(index, kp, bearings, valid, image)

    selector = KeyframeSelector(camera, SparseSettings(), 0)
    pairs = np.stack([np.arange(80), np.arange(80)], axis=1)
    moved, kept = selector._registered(view(0, uv1, first), view(1, found, second), pairs)
    assert len(kept) >= 78
    err = np.linalg.norm(moved.keypoints.uv[kept[:, 1]] - truth[kept[:, 1]], axis=1)
    assert np.median(err) < 0.03 and np.percentile(err, 90) < 0.1
    assert np.linalg.norm(np.mean(moved.keypoints.uv[kept[:, 1]] - truth[kept[:, 1]], axis=0)) < 0.01
    b, _ = camera.unproject(moved.keypoints.uv[kept[:, 1]])
    np.testing.assert_allclose(moved.bearings[kept[:, 1]], b, atol=1e-12)
    off = KeyframeSelector(camera, SparseSettings(match_patch_px=None), 0)
    same, all_pairs = off._registered(view(0, uv1, first), view(1, found, second), pairs)
    assert np.array_equal(same.keypoints.uv, found) and len(all_pairs) == 80
