"""Back end: sliding-window bundle adjustment with cylinder priors (fisheye paper III-C, III-D)."""

from pipemap.backend.bundle import BundleProblem, BundleResult, BundleState, Observations, solve_window

__all__ = ["BundleProblem", "BundleResult", "BundleState", "Observations", "solve_window"]
