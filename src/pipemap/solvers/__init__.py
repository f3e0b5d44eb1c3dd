"""Solver machinery shared by the paper stages: robust statistics (Huber, MAD), one Levenberg-Marquardt
driver for small dense or tall sparse problems, the staged LM with outlier passes and the Schur
complement of the bundle adjustments. Pure maths: nothing here knows of cameras, pipes or tees."""

from pipemap.solvers.lm import LMResult, levenberg_marquardt
from pipemap.solvers.robust import MAD_TO_SIGMA, huber_cost, huber_irls, huber_weights, mad_inliers, mad_sigma

__all__ = ["LMResult", "levenberg_marquardt", "MAD_TO_SIGMA", "huber_cost", "huber_irls", "huber_weights",
           "mad_inliers", "mad_sigma"]
