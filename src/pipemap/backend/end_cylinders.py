"""Cylinders fitted to the two ends of a mapped straight section (fisheye paper III-D, Fig. 4a).

Before a T-intersection is solved, a straight cylinder is fitted to the scene points of the first
and of the last metre of each straight section, parameterised (eq. 4) relative to the section's
first and last pose respectively: the C_b and C_r of the tee model.
"""

from __future__ import annotations

import numpy as np

from pipemap.errors import PipemapError
from pipemap.geometry.cylinder import CylinderFit, fit_cylinder
from pipemap.geometry.se3 import as_rt

_MAX_AXIS_DISTANCE = 2.0  # points farther than this many radii from the path are not on this pipe


def fit_end_cylinder(poses, points, radius: float, *, end: str = "last", length_m: float = 1.0,
                     **fit_options) -> CylinderFit:
    """Fit a cylinder of the given radius to the points beside the section's first or last `length_m`
    of travel, relative to its first or last pose (T_wc, `poses` in travel order).

    The pipe direction starts from the chord of the camera path over that length (the end pose's optical
    axis when the path is shorter than 1 cm); points count when they lie between the end pose and
    `length_m` back along it (not beyond the end, where the junction starts) and within two radii of
    the chord. `fit_options` go to `fit_cylinder`.
    """
    if end not in ("first", "last"):
        raise ValueError(f"end must be 'first' or 'last', got {end!r}")
    if not np.isfinite(length_m) or length_m <= 0:
        raise PipemapError(f"the fitted length of a section end must be positive, got {length_m!r} m")
    R, t = as_rt(poses)
    if R.ndim != 3 or len(R) == 0:
        raise ValueError(f"poses must be (N, 4, 4) with N >= 1, got shape {R.shape[:-2]}")
    P = np.asarray(points, float)
    if P.ndim != 2 or P.shape[1] != 3:
        raise ValueError(f"points must be (M, 3), got {P.shape}")
    order = np.arange(len(R)) if end == "first" else np.arange(len(R))[::-1]
    c = t[order]
    arc = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(c, axis=0), axis=1))]
    seg = c[arc <= length_m]
    chord = seg[-1] - seg[0]
    ref_R, ref_t = R[order[0]], t[order[0]]
    if np.linalg.norm(chord) < 0.01:
        inward = ref_R[:, 2] * (1.0 if end == "first" else -1.0)
    else:
        inward = chord / np.linalg.norm(chord)
    v = P - ref_t
    s = v @ inward
    across = np.linalg.norm(v - s[:, None] * inward, axis=1)
    near = (s >= 0) & (s <= length_m) & (across <= _MAX_AXIS_DISTANCE * radius) & np.all(np.isfinite(P), axis=1)
    if near.sum() < 5:
        raise PipemapError(f"only {int(near.sum())} points lie along the {end} {length_m:g} m of the section; "
                           "a cylinder fit needs at least 5")
    return fit_cylinder(P[near], radius, reference=(ref_R, ref_t), direction=inward, **fit_options)


def fit_end_cylinders(poses, points, radius: float, length_m: float = 1.0,
                      **fit_options) -> tuple[CylinderFit, CylinderFit]:
    """(cylinder of the first `length_m` relative to the first pose, cylinder of the last relative to the last)."""
    return (fit_end_cylinder(poses, points, radius, end="first", length_m=length_m, **fit_options),
            fit_end_cylinder(poses, points, radius, end="last", length_m=length_m, **fit_options))


__all__ = ["fit_end_cylinder", "fit_end_cylinders"]
