"""Self-checks of the straight-pipe methods (the 2010 report's dense and sparse VO): one section,
the pipe, rated from the motion model's residual, how well the images fixed the camera's mount
(its offset sets the scale) and, for sparse VO, the batch's reprojection RMS and the keyframes
that had no point to hold them.

The motion model: a crawler's speed changes smoothly, so a step along the pipe far from the
median of the steps around it is a registration that slipped (a repeated texture matched one
period off, a blurred frame). Its fraction is rated with quality.weak_links.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import median_filter

from pipemap.config import QualitySettings
from pipemap.quality.verdict import Check, RunVerdict, SectionVerdict, above, SUSPECT

_NEIGHBOURS = 5  # steps in the running median of the motion model
_SLIP = 0.3  # a step this far (relative) from the running median ...
_SLIP_FLOOR = 0.001  # ... and this many metres: a slip


def motion_slips(along: np.ndarray, times: np.ndarray) -> float | None:
    """Fraction of steps between consecutive poses (`along`: metres along the pipe at `times`) whose speed leaves
    the running median of its neighbours' (keyframes need not be evenly spaced in time)."""
    along, times = np.asarray(along, float), np.asarray(times, float)
    dt = np.diff(times)
    if len(dt) < _NEIGHBOURS or np.any(dt <= 0):
        return None
    speed = np.diff(along) / dt
    smooth = median_filter(speed, size=_NEIGHBOURS, mode="nearest")
    off = np.abs(speed - smooth) * dt  # metres the step is off the model
    return float(np.mean(off > np.maximum(_SLIP * np.abs(smooth) * dt, _SLIP_FLOOR)))


def wall_distance_along_view(offset_m, angle_deg: float, radius: float) -> float:
    """Distance from a camera at `offset_m` (C_X, C_Y) from the axis, looking towards +Y at `angle_deg` to the
    axis, to the wall along its optical axis: the distance its image motion is scaled by, as the sparse
    odometry measures its offset's sigma against (behind the axis, C_Y < 0, the wall is further away)."""
    c_x, c_y = (float(v) for v in offset_m)
    across = np.sqrt(max(radius * radius - c_x * c_x, 0.0)) - c_y
    return float(across / max(np.sin(np.radians(angle_deg)), 1e-9))


def _mount_checks(v: SectionVerdict, mount, radius: float, q: QualitySettings) -> None:
    if mount is None:
        return
    if not mount.determined and mount.source != "given":
        v.checks.append(Check("mount", None, SUSPECT, "the images do not fix the camera's offset from the axis, on "
                              "which the scale rests"))
    if mount.sigma is None:
        return
    wall = wall_distance_along_view(mount.offset_m, mount.angle_deg, radius)
    sd = float(np.hypot(*np.nan_to_num(mount.sigma[2:]))) if np.isfinite(mount.sigma[2:]).any() else None
    v.figures["mount_offset_sigma_m"] = sd
    v.checks.append(above("mount", None if sd is None else sd / max(wall, 1e-9), q.mount_sigma,
                          "mount offset's standard deviation, fraction of the wall distance,",
                          fmt=lambda x: f"{100 * x:.2f} %"))


def straight_verdict(method: str, indices: np.ndarray, times: np.ndarray, positions_along: np.ndarray, mount,
                     radius: float,
                     q: QualitySettings, batch_rms_px: float | None = None, unconstrained: int | None = None,
                     scale_source: str | None = None) -> RunVerdict:
    """One section, the pipe: `positions_along` (metres) of the frames or keyframes in `indices` at `times`."""
    idx = np.asarray(indices, int)
    v = SectionVerdict(0, "pipe", int(idx[0]) if len(idx) else 0, int(idx[-1]) if len(idx) else 0, len(idx))
    v.figures["method"] = method
    slips = motion_slips(positions_along, times)
    v.figures["motion_slips"] = slips
    v.checks.append(above("motion model", slips, q.weak_links, "steps off the motion model",
                          fmt=lambda x: f"{100 * x:.1f} %"))
    if len(idx) < q.min_keyframes:
        v.checks.append(Check("keyframes", len(idx), SUSPECT, f"only {len(idx)} keyframes"))
    _mount_checks(v, mount, radius, q)
    if batch_rms_px is not None and np.isfinite(batch_rms_px):
        v.figures["batch_rms_px"] = float(batch_rms_px)
        v.checks.append(above("reprojection", float(batch_rms_px), q.rms_px, "batch reprojection RMS (px)"))
    if unconstrained is not None and len(idx):
        v.figures["keyframes_without_points"] = int(unconstrained)
        v.checks.append(above("unheld keyframes", unconstrained / len(idx), q.weak_links,
                              "keyframes without a point seen before", fmt=lambda x: f"{100 * x:.1f} %"))
    if scale_source is not None:
        v.figures["scale_source"] = scale_source
    return RunVerdict([v])


__all__ = ["motion_slips", "straight_verdict"]
