"""How far ahead of a camera the pipe's wall is still the straight cylinder beside it.

A straight window's cylinder term holds every wall point its cameras see, and a fisheye sees the wall far down
the pipe. Where the pipe bends ahead, that wall is no longer the window's cylinder: held on it, it turns the
window's cameras towards the bend, a few tenths of a degree over the last metre before an elbow, and the elbow's
angle and vertex with them. Where the pipe runs on through a tee, the wall ahead is still the same cylinder and
holds the heading: it is worth keeping there.

A bend shows in the wall ahead as one side coming in: the bend's outer wall (the side the pipe turns away from,
facing the camera) is nearer the straight axis than its radius, by about x^2 / (2 R_bend) a distance x into the
bend, while an opening (a branch, the pipe's end) only takes wall away or shows points beyond it. So the wall
ahead is cut where, in a slice of it, the median
signed distance of the points in some sector of clock positions falls below -`inward_m` of the cylinder fitted
to the wall just behind the camera, and clearly so for the points' scatter. Just behind: a run's pieces sag and
meet with small offsets, so a cylinder fitted to a whole window's wall (metres of it) can miss the wall at its
front by millimetres; fitted to the window's full length it cut the wall ahead in a quarter of paper-loop route A's
straight windows and Table I went 0.040 -> 0.116 %.
"""

from __future__ import annotations

import numpy as np

from pipemap.geometry.cylinder import axis_frame, fit_cylinder

SECTORS = 8  # clock sectors of 45 deg
REFERENCE_RADII = 2.0  # the reference cylinder is fitted to the wall this many radii behind the camera
MIN_SECTOR_POINTS = 8
# a sector comes in when its median is this many of its standard errors inside the wall: some 200 sectors and
# slices are looked at in each window, so a wall that stays straight must not show one by chance
SIGNIFICANCE = 5.0


def straight_reach(points: np.ndarray, camera: np.ndarray, direction: np.ndarray, radius: float, *,
                   inward_m: float, slice_m: float, huber: float) -> float:
    """Distance ahead of `camera` (along the unit `direction` of travel) where the wall the `points` (M, 3) lie
    on stops being the cylinder of radius `radius` fitted to those up to REFERENCE_RADII radii behind it: the near
    edge of the first slice (`slice_m` long, half-overlapping) in which one clock sector's points come in by more
    than `inward_m` (median). inf when none does or no cylinder fits."""
    P = np.asarray(points, float)
    u = np.asarray(direction, float) / np.linalg.norm(direction)
    ahead = (P - camera) @ u
    beside = (ahead <= 0) & (ahead >= -REFERENCE_RADII * radius)
    far = ahead > 0
    if beside.sum() < 3 * MIN_SECTOR_POINTS or far.sum() < MIN_SECTOR_POINTS:
        return np.inf
    try:
        fit = fit_cylinder(P[beside], radius, direction=u, huber=huber)
    except (ValueError, np.linalg.LinAlgError):
        return np.inf
    cyl = fit.cylinder
    frame = axis_frame(cyl.direction)
    signed = cyl.distance(P[far])
    v = (P[far] - cyl.origin) @ frame
    sector = (np.floor((np.arctan2(v[:, 1], v[:, 0]) + np.pi) / (2 * np.pi / SECTORS)).astype(int)) % SECTORS
    x = ahead[far]
    for start in np.arange(0.0, float(x.max()), slice_m / 2):
        inside = (x >= start) & (x < start + slice_m)
        if inside.sum() < MIN_SECTOR_POINTS:
            continue
        if _comes_in(sector[inside], signed[inside], inward_m):
            return float(start)
    return np.inf


def _comes_in(sector: np.ndarray, signed: np.ndarray, inward_m: float) -> bool:
    """Whether the points of one slice (clock `sector`, `signed` distance from the wall) lie inside the wall in
    some sector of at least MIN_SECTOR_POINTS: by more than `inward_m` (median) and by more than SIGNIFICANCE
    standard errors of that median. Their scatter is the slice's, about each sector's median: a handful of
    points' own MAD is too unsteady to judge by."""
    sectors = np.unique(sector)
    medians = np.array([np.median(signed[sector == k]) for k in sectors])
    counts = np.array([np.count_nonzero(sector == k) for k in sectors])
    spread = 1.4826 * float(np.median(np.abs(signed - medians[np.searchsorted(sectors, sector)])))
    error = 1.2533 * spread / np.sqrt(counts)
    return bool(np.any((counts >= MIN_SECTOR_POINTS) & (medians < -np.maximum(inward_m, SIGNIFICANCE * error))))
