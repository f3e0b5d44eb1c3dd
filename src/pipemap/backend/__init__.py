"""Back end: sliding-window bundle adjustment with cylinder priors (fisheye paper III-C), the tee
model that joins straight sections (III-D) and loop closure by pose-graph optimisation (III-E)."""

from pipemap.backend.bundle import BundleProblem, BundleResult, BundleState, Observations, solve_window
from pipemap.backend.end_cylinders import fit_end_cylinder, fit_end_cylinders
from pipemap.backend.junction import JunctionProblem, JunctionResult, solve_junction

__all__ = ["BundleProblem", "BundleResult", "BundleState", "Observations", "solve_window", "fit_end_cylinder",
           "fit_end_cylinders", "JunctionProblem", "JunctionResult", "solve_junction"]
