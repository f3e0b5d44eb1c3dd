"""The 2010 report's straight-pipe visual odometry: dense registration (section 4), the sparse
cylinder-constrained method (section 5) and unrolled wall images (section 6)."""

from pipemap.straight.dense import DENSE_METHODS, DenseResult, estimate_shifts, run_dense
from pipemap.straight.registration import adaptive_full_search, full_search, hybrid, lucas_kanade
from pipemap.straight.scale import pixels_per_metre
from pipemap.straight.sparse.run import SPARSE_METHOD, SparseResult, run_sparse
from pipemap.straight.undistort import Rectifier

__all__ = ["DENSE_METHODS", "DenseResult", "Rectifier", "SPARSE_METHOD", "SparseResult", "adaptive_full_search",
           "estimate_shifts", "full_search", "hybrid", "lucas_kanade", "pixels_per_metre", "run_dense", "run_sparse"]
