"""benchmarks/bench_spread.py: the spread of a run's figures over the seeds of its random choices."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

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
    assert s["table_i_max_abs_pct"] == {"min": 0.04, "median": 0.11, "max": 0.21}
    assert s["ate_rigid_mm"] == {"min": 5.8, "median": 12.0, "max": 12.1}
    assert s["path_length_error_pct"]["median"] == -0.017
    assert s["wall_s"]["max"] == 166.0


def test_a_figure_some_runs_lack_is_left_out(bench):
    # a straight pipe has no Table I: its spread has none rather than one over the runs that happen to have it
    runs = [{"table_i_max_abs_pct": None, "ate_rigid_mm": 1.0}, {"table_i_max_abs_pct": 0.1, "ate_rigid_mm": 3.0}]
    s = bench.spread(runs)
    assert "table_i_max_abs_pct" not in s
    assert s["ate_rigid_mm"] == {"min": 1.0, "median": 2.0, "max": 3.0}
