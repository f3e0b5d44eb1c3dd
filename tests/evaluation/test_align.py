import numpy as np
import pytest

from pipemap.evaluation.align import umeyama
from pipemap.geometry.rotations import exp_so3


def _random_transform(rng):
    return exp_so3(rng.normal(size=3)), rng.normal(scale=5.0, size=3)


@pytest.mark.parametrize("seed", range(5))
def test_recovers_random_se3_exactly(seed):
    rng = np.random.default_rng(seed)
    R, t = _random_transform(rng)
    src = rng.normal(scale=3.0, size=(50, 3))
    R_est, t_est, s_est = umeyama(src, src @ R.T + t, with_scale=False)
    np.testing.assert_allclose(R_est, R, atol=1e-9)
    np.testing.assert_allclose(t_est, t, atol=1e-9)
    assert s_est == 1.0


@pytest.mark.parametrize("seed", range(5))
def test_recovers_random_sim3_exactly(seed):
    rng = np.random.default_rng(100 + seed)
    R, t = _random_transform(rng)
    s = rng.uniform(0.2, 5.0)
    src = rng.normal(scale=3.0, size=(50, 3))
    a = umeyama(src, s * src @ R.T + t, with_scale=True)
    np.testing.assert_allclose(a.rotation, R, atol=1e-9)
    np.testing.assert_allclose(a.translation, t, atol=1e-9)
    assert a.scale == pytest.approx(s, abs=1e-9)
    np.testing.assert_allclose(a.apply(src), s * src @ R.T + t, atol=1e-9)
    np.testing.assert_allclose(a.matrix()[:3, :3], s * R, atol=1e-9)


def test_never_returns_a_reflection_and_fits_least_squares():
    rng = np.random.default_rng(7)
    src = rng.normal(size=(30, 3))
    mirrored = src * np.array([1.0, 1.0, -1.0])
    a = umeyama(src, mirrored)
    assert np.linalg.det(a.rotation) == pytest.approx(1.0, abs=1e-12)
    assert np.allclose(a.rotation @ a.rotation.T, np.eye(3), atol=1e-12)


def test_collinear_points_as_in_a_straight_pipe_align_with_zero_residual():
    rng = np.random.default_rng(3)
    R, t = _random_transform(rng)
    src = np.outer(np.linspace(0, 6, 40), [0.3, -0.2, 0.9])
    dst = src @ R.T + t
    a = umeyama(src, dst)
    np.testing.assert_allclose(a.apply(src), dst, atol=1e-9)


def test_shape_errors():
    with pytest.raises(ValueError):
        umeyama(np.zeros((4, 3)), np.zeros((5, 3)))
    with pytest.raises(ValueError):
        umeyama(np.zeros((4, 2)), np.zeros((4, 2)))
