"""The one Levenberg-Marquardt driver and the robust statistics it is used with."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from pipemap.solvers import huber_irls, levenberg_marquardt, mad_inliers, mad_sigma


def _rosenbrock(x):
    r = np.array([10.0 * (x[1] - x[0] ** 2), 1.0 - x[0]])
    J = np.array([[-20.0 * x[0], 10.0], [-1.0, 0.0]])
    return r, J


def test_a_curved_valley_is_followed_to_its_minimum():
    out = levenberg_marquardt(_rosenbrock, lambda x, d: x + d, np.array([-1.2, 1.0]), iterations=200)
    np.testing.assert_allclose(out.state, [1.0, 1.0], atol=1e-6)
    assert out.cost < 1e-12 and out.iterations < 200


def _line(points, sparse: bool):
    t, y = points

    def evaluate(p):
        r = p[0] + p[1] * t - y
        J = np.column_stack([np.ones_like(t), t])
        return r, (sp.csr_matrix(J) if sparse else J)
    return evaluate


@pytest.mark.parametrize("sparse", [False, True])
def test_huber_weights_keep_a_line_fit_off_its_outliers(sparse):
    rng = np.random.default_rng(3)
    t = np.linspace(0.0, 10.0, 200)
    y = 0.5 + 2.0 * t + rng.normal(0.0, 0.05, t.size)
    y[::10] += 25.0  # one in ten points far off
    plain = levenberg_marquardt(_line((t, y), sparse), lambda p, d: p + d, np.zeros(2), iterations=50)
    robust = levenberg_marquardt(_line((t, y), sparse), lambda p, d: p + d, np.zeros(2), iterations=50,
                                 cost=huber_irls(0.1))
    assert abs(plain.state[0] - 0.5) > 1.0  # least squares is dragged up by the outliers
    np.testing.assert_allclose(robust.state, [0.5, 2.0], atol=0.05)


def test_grouped_huber_weighs_two_component_errors_by_their_norm():
    cost = huber_irls(1.0, group=2)
    total, w = cost(np.array([0.3, 0.4, 3.0, 4.0]))  # norms 0.5 (inside) and 5 (outside)
    assert total == pytest.approx(0.25 + (2 * 5 - 1))
    np.testing.assert_allclose(w, [1.0, 1.0, 0.2, 0.2])


def test_mad_sigma_is_a_normal_sigma_and_rejects_what_lies_beyond_k_of_them():
    x = np.random.default_rng(0).normal(1.0, 2.0, 100_000)
    assert mad_sigma(x) == pytest.approx(2.0, rel=0.02)
    assert mad_sigma(np.abs(x - 1.0), centre=0.0) == pytest.approx(2.0, rel=0.02)  # sizes, spread from zero
    keep = mad_inliers(x, 3.0)
    assert keep.mean() == pytest.approx(0.9973, abs=0.002)


def test_mad_sigma_along_an_axis_is_the_same_as_by_numpys_median():
    # The median along an axis is taken by one partition (odd and even lengths, keepdims or not); a row with a
    # NaN goes to np.median, which carries it.
    rng = np.random.default_rng(5)
    for shape, axis in (((40, 32), 1), ((40, 31), 1), ((6, 9, 4), 0), ((3, 1), 1)):
        x = rng.normal(size=shape)
        for keepdims in (False, True):
            want = 1.4826 * np.median(np.abs(x - np.median(x, axis=axis, keepdims=True)), axis=axis, keepdims=keepdims)
            assert np.array_equal(mad_sigma(x, axis=axis, keepdims=keepdims), want)
    x = rng.normal(size=(4, 6))
    x[1, 2] = np.nan
    got = mad_sigma(x, centre=0.0, axis=1)
    assert np.isnan(got[1]) and np.array_equal(got[[0, 2, 3]], 1.4826 * np.median(np.abs(x[[0, 2, 3]]), axis=1))
