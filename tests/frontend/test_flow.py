"""The local second-order image motion fitted from neighbouring matches (frontend/flow.py)."""

from __future__ import annotations

import numpy as np

from pipemap.frontend.flow import local_quadratic_motion


def _motion(x):
    """A smooth, not polynomial, motion like a fisheye's radial flow: y = c + (x - c) * g(|x - c|^2)."""
    c = np.array([160.0, 120.0])
    d = x - c
    r2 = np.sum(d * d, axis=-1, keepdims=True)
    return c + d * (1.05 + 0.3 * np.sin(r2 / 40000.0)) + np.array([0.4, -0.2])


def _derivatives(f, x, h=1e-3):
    J = np.stack([(f(x + [h, 0]) - f(x - [h, 0])) / (2 * h), (f(x + [0, h]) - f(x - [0, h])) / (2 * h)], -1)
    e = [np.array([h, 0]), np.array([0, h])]
    H = np.empty(x.shape[:-1] + (2, 2, 2))
    for a in range(2):
        for b in range(2):
            H[..., :, a, b] = (f(x + e[a] + e[b]) - f(x + e[a] - e[b])
                               - f(x - e[a] + e[b]) + f(x - e[a] - e[b])) / (4 * h * h)
    return J, H


def test_recovers_the_first_and_second_derivatives_of_a_smooth_motion():
    rng = np.random.default_rng(0)
    src = rng.uniform(0, 320, (3000, 2))
    dst = _motion(src) + rng.normal(0, 0.05, src.shape)
    at = rng.uniform(60, 260, (200, 2))
    J, H, ok = local_quadratic_motion(src, dst, at)
    Jt, Ht = _derivatives(_motion, at)
    assert ok.all()
    assert np.sqrt(np.mean((J - Jt) ** 2)) < 3e-3
    # second derivatives of ~1e-3 px/px^2 are what bend a patch match; a random error is harmless,
    # a systematic one is not
    assert np.sqrt(np.mean(Ht**2)) > 1e-3
    assert np.sqrt(np.mean((H - Ht) ** 2)) < 4e-4
    assert np.abs(np.mean(H - Ht, axis=0)).max() < 5e-5
    J, H, ok = local_quadratic_motion(src, _motion(src), at)  # exact matches
    assert np.abs(H - Ht).max() < 3e-4


def test_wrong_matches_among_the_neighbours_are_ignored():
    rng = np.random.default_rng(1)
    src = rng.uniform(0, 320, (3000, 2))
    dst = _motion(src) + rng.normal(0, 0.05, src.shape)
    bad = rng.random(len(src)) < 0.1
    dst[bad] += rng.uniform(-8, 8, (bad.sum(), 2))
    at = rng.uniform(60, 260, (200, 2))
    J, H, ok = local_quadratic_motion(src, dst, at)
    _, Ht = _derivatives(_motion, at)
    assert ok.mean() > 0.95
    err = H[ok] - Ht[ok]
    assert np.sqrt(np.mean(err**2)) < 8e-4
    assert np.abs(np.mean(err, axis=0)).max() < 1e-4


def test_points_outside_their_neighbourhood_or_without_one_get_no_bend():
    rng = np.random.default_rng(2)
    src = rng.uniform(100, 200, (500, 2))
    at = np.array([[150.0, 150.0], [400.0, 150.0]])  # inside the cloud, far outside it
    J, H, ok = local_quadratic_motion(src, _motion(src), at)
    assert ok.tolist() == [True, False]
    assert np.array_equal(J[1], np.eye(2)) and not H[1].any()
    J, H, ok = local_quadratic_motion(src[:5], _motion(src[:5]), at)  # too few matches
    assert not ok.any() and not H.any()


def test_a_neighbourhood_on_a_line_gets_no_bend_and_leaves_the_others_theirs():
    # Matches along one line fix no quadratic across it: that point's normal matrix is singular, which the
    # batched test of the well-conditioned fits must catch without losing the other points' fits.
    rng = np.random.default_rng(3)
    cloud = rng.uniform(100, 200, (400, 2))
    line = np.stack([np.linspace(400, 500, 60), np.full(60, 300.0)], axis=1)
    src = np.concatenate([cloud, line])
    at = np.array([[150.0, 150.0], [450.0, 300.0]])
    J, H, ok = local_quadratic_motion(src, _motion(src), at)
    assert ok.tolist() == [True, False]
    assert np.array_equal(J[1], np.eye(2)) and not H[1].any()
    _, Ht = _derivatives(_motion, at[:1])
    assert np.abs(H[0] - Ht[0]).max() < 1e-4
