"""Sections judged against the truth: path length between poses 0.1 m apart, worst leg of a turn-around."""

from __future__ import annotations

import numpy as np
import pytest

from pipemap.evaluation.verdicts import _worst_leg, confusion, error_class


def test_worst_leg_keeps_forward_and_reverse_from_cancelling():
    x = np.r_[np.arange(0, 3.01, 0.1), np.arange(2.9, -0.01, -0.1)]
    pg = np.c_[x, np.zeros_like(x), np.zeros_like(x)]
    pe = pg.copy()
    pe[:31, 0] *= 0.998  # forward leg 0.2 % short
    pe[31:, 0] = pe[30, 0] - (3.0 - x[31:]) * 1.002  # reverse leg 0.2 % long
    truth, err = _worst_leg(pe, pg)
    assert truth == pytest.approx(6.0)
    assert abs(err) == pytest.approx(0.2, rel=1e-6)


def test_confusion_counts_by_error_class():
    rows = [{"error_pct": 0.05, "truth_m": 2.0, "rating": "good"},
            {"error_pct": -0.5, "truth_m": 2.0, "rating": "good"},
            {"error_pct": 1.7, "truth_m": 3.0, "rating": "suspect"},
            {"error_pct": None, "truth_m": None, "rating": "good"}]
    t = confusion(rows)
    assert t["within 0.1 %"]["good"] == 1 and t["0.1-1 %"]["good"] == 1 and t["over 1 %"]["suspect"] == 1
    assert error_class(-1.01) == "over 1 %"
