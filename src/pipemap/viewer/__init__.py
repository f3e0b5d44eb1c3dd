"""`pipemap report`: a self-contained HTML viewer of a result folder (3D network, unrolled walls with a
chainage x clock grid, deformation, observations)."""

from pipemap.viewer.page import VIEWER, ViewerSummary, write_viewer

__all__ = ["VIEWER", "ViewerSummary", "write_viewer"]
