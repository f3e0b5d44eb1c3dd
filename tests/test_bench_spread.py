"""benchmarks/bench_spread.py: the spread of a run's figures over the seeds of its random choices."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

_DIR = Path(__file__).resolve().parents[1] / "benchmarks"


@pytest.fixture(scope="module")
def bench():
    sys.path.insert(0, str(_DIR))  # bench_spread imports bench_network and tree_memory beside it
    try:
        spec = importlib.util.spec_from_file_location("bench_spread", _DIR / "bench_spread.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        yield module
    finally:
        sys.path.remove(str(_DIR))


def test_spread_gives_each_figure_its_minimum_median_and_maximum(bench):
    runs = [{"table_i_max_abs_pct": 0.04, "ate_rigid_mm": 5.8, "path_length_error_pct": -0.019, "wall_s": 160.0,
             "cpu_s": 257.0},
            {"table_i_max_abs_pct": 0.21, "ate_rigid_mm": 12.1, "path_length_error_pct": -0.016, "wall_s": 152.0,
             "cpu_s": 240.0},
            {"table_i_max_abs_pct": 0.11, "ate_rigid_mm": 12.0, "path_length_error_pct": -0.017, "wall_s": 166.0,
             "cpu_s": 262.0}]
    s = bench.spread(runs)
    assert {k: s["table_i_max_abs_pct"][k] for k in ("min", "median", "max")} == {"min": 0.04, "median": 0.11,
                                                                                  "max": 0.21}
    assert s["table_i_max_abs_pct"]["mean"] == pytest.approx(0.12)
    assert s["table_i_max_abs_pct"]["sd"] == pytest.approx(np.std([0.04, 0.21, 0.11], ddof=1))
    assert {k: s["ate_rigid_mm"][k] for k in ("min", "median", "max")} == {"min": 5.8, "median": 12.0, "max": 12.1}
    assert s["path_length_error_pct"]["median"] == -0.017
    assert s["wall_s"]["max"] == 166.0


def test_a_figure_some_runs_lack_is_left_out(bench):
    # a straight pipe has no Table I: its spread has none rather than one over the runs that happen to have it
    runs = [{"table_i_max_abs_pct": None, "ate_rigid_mm": 1.0}, {"table_i_max_abs_pct": 0.1, "ate_rigid_mm": 3.0}]
    s = bench.spread(runs)
    assert "table_i_max_abs_pct" not in s
    assert {k: s["ate_rigid_mm"][k] for k in ("min", "median", "max")} == {"min": 1.0, "median": 2.0, "max": 3.0}


def _run(t1_t4: float, ate: float, t1_t2: float = -0.02) -> dict:
    return {"table_i": [{"pair": "T1-T2", "error_pct": t1_t2}, {"pair": "T1-T4", "error_pct": t1_t4}],
            "table_i_max_abs_pct": max(0.02, abs(t1_t4)), "ate_rigid_mm": ate}


def test_each_pair_gets_its_signed_spread(bench):
    s = bench.spread([_run(-0.1, 5.0), _run(+0.1, 7.0), _run(-0.3, 9.0)])
    assert s["pair T1-T4"]["mean"] == pytest.approx(-0.1)
    assert s["pair T1-T4"]["min"] == -0.3 and s["pair T1-T2"]["sd"] == pytest.approx(0.0)


def test_compare_gives_the_difference_its_standard_error_and_welch_p(bench):
    from scipy import stats

    base = [_run(v, 5.0 + i) for i, v in enumerate([0.02, -0.02, -0.08, 0.07, -0.16, -0.23, -0.13, -0.13])]
    new = [_run(v, 8.0 + 0.1 * i, -0.02 + 0.001 * i) for i, v in enumerate([-0.15, -0.21, -0.26, -0.30])]
    c = bench.compare(new, base)["pair T1-T4"]
    a, b = np.array([-0.15, -0.21, -0.26, -0.30]), np.array([0.02, -0.02, -0.08, 0.07, -0.16, -0.23, -0.13, -0.13])
    assert c["difference"] == pytest.approx(a.mean() - b.mean())
    assert c["se"] == pytest.approx(np.sqrt(a.var(ddof=1) / 4 + b.var(ddof=1) / 8))
    assert c["p"] == pytest.approx(stats.ttest_ind(a, b, equal_var=False).pvalue)
    assert c["p"] < 0.05 and (c["runs"], c["baseline_runs"]) == (4, 8)
    # the same runs against themselves: no difference
    same = bench.compare(base, base)["pair T1-T4"]
    assert same["difference"] == pytest.approx(0.0) and same["p"] == pytest.approx(1.0)
    assert bench.compare(base, base)["pair T1-T2"]["p"] == 1.0
